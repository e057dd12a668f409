"""Objectives: the cost of a closed-loop run, one number per candidate (lower is better).

Every objective is a function of a ``Run``: the arrays a run produces (time, measured
temperature, target, duty, protection trips) for N candidates on one clock, so the same code
scores a batch of lanes, a scalar twin (N = 1) and the idealised linear loop. Registry
``OBJECTIVES``: name -> (function, one-line description); docs/tuning.md gives each formula.

- ``heater`` (the default): the project's heater objective, in seconds (see ``heater_cost``).
- ``itae``: integral of (t - t_phase) |e| dt, the clock restarting at the heat-up and at each
  disturbance, so a late disturbance weighs as much as an early one.
- ``seed000_nm``, ``seed000_pso``, ``seed000_de``: seed 000 (Lab Units 13 & 14, "digital twin
  for PID tuning") cost functions of its Nelder-Mead, PSO and DE listings, with its weights, on
  its own metric definitions (``seed000_metrics``) over the heat-up.
- ``seed002_q``: seed 002 (OCALO-PID, Zhou et al. 2024) equation (17), Q = integral of
  (w1 |e| + w2 u^2 + w3 |e| while overshooting) dt, over the whole run.

Gains in the gain penalties of seed 000 are on the plant's input scale (``Run.gains``: the
paper's units per degC, W/degC for a lumped heater), as the seed's code penalises them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from firmware_port.marlin.constants import TEMP_HYSTERESIS_C
from twin.streaming import ScoreSpec, ScoreTotals

# heater objective (seconds of cost)
BAND_C = 2.0  # "at temperature": twin/metrics.py's default band_c
OVERSHOOT_BOUND_C = float(TEMP_HYSTERESIS_C)  # Marlin's M109 hysteresis (Configuration.h TEMP_HYSTERESIS, 3 C)
OVERSHOOT_S_PER_C = 30.0  # each degC of overshoot beyond the bound costs as much as 30 s of heat-up
HOLD_S_PER_C = 100.0  # each degC of mean |error| while holding costs 100 s
CHATTER_BOUND = 0.02  # mean |duty change| per reading allowed while holding: about 2.5 soft-PWM counts of 127
CHATTER_S = 10_000.0  # cost per unit of mean |duty change| beyond the bound: 0.01 costs as 1 C of hold error
UNREACHED_S = 1000.0  # added to the heat-up time when the band is never reached
TRIP_S = 10_000.0  # a protection trip (MAXTEMP, runaway, heating failed): worse than any working run

# seed 000's weights, as printed in its listings (overshoot, settling, steady-state error, gains)
SEED000_NM = (10.0, 1.0, 100.0, 0.1)  # + 0.1 (Kp^2 + Ki^2 + Kd^2)
SEED000_PSO = (20.0, 5.0, 10.0, 0.0)
SEED000_DE = (100.0, 20.0, 50.0, 0.1)  # + 0.1 (Kp + Ki + Kd)
SEED000_BAND = 0.05  # settling band: 5 % of the setpoint
SEED002_W = (0.999, 0.001, 100.0)  # seed 002 section 4: "usually w1 = 0.999, w2 = 0.001", "w3 = 100"
SEED002_BAND = 0.02  # its 2 % error bars (settling and recovery)


@dataclass(frozen=True)
class Run:
    """N closed-loop runs on one clock; arrays (rows, N), or (rows,) for one run.

    t_s: sample times from the heat-up's start; temp_c: measured temperature; duty: heater duty
    0..1 (the firmware's) or the controller's output in plant-input units / input_full_scale
    (idealised loop, unbounded); target_c: the setpoint; start_c: the temperature the heat-up
    starts from; disturbances_s: the times of the disturbances (the first ends the heat-up);
    tripped: (N,) a protection trip; gains: (N, 3) Kp, Ki, Kd in plant-input units per degC of a PID
    family's candidates, None for other controllers; input_full_scale: the plant input at duty 1
    (W for a lumped heater). ``streamed``: the heater objective's inputs accumulated during the run
    (twin/streaming.py) by a batch that kept no trace (then the arrays have no rows and only
    ``heater_cost`` can score the run).
    """

    t_s: np.ndarray
    temp_c: np.ndarray
    duty: np.ndarray
    target_c: float
    start_c: float
    disturbances_s: tuple[float, ...]
    tripped: np.ndarray
    gains: np.ndarray | None
    input_full_scale: float = 1.0
    streamed: ScoreTotals | None = None

    def __post_init__(self) -> None:
        temp, duty = np.asarray(self.temp_c, float), np.asarray(self.duty, float)
        if temp.ndim == 1:
            temp, duty = temp[:, None], duty[:, None]
        object.__setattr__(self, "temp_c", temp)
        object.__setattr__(self, "duty", duty)
        object.__setattr__(self, "t_s", np.asarray(self.t_s, float))
        object.__setattr__(self, "tripped", np.broadcast_to(np.asarray(self.tripped, bool), (temp.shape[1],)))
        if self.gains is not None:
            object.__setattr__(self, "gains", np.asarray(self.gains, float).reshape(temp.shape[1], 3))
        if temp.shape != duty.shape or temp.shape[0] != self.t_s.size:
            raise ValueError(f"run arrays disagree: t_s {self.t_s.shape}, temp_c {temp.shape}, duty {duty.shape}")

    @property
    def n(self) -> int:
        return self.temp_c.shape[1]

    @property
    def heatup_end_s(self) -> float:
        return self.disturbances_s[0] if self.disturbances_s else float(self.t_s[-1]) + 1.0

    @property
    def error_c(self) -> np.ndarray:
        """e = target - temp, (rows, N)."""
        return self.target_c - self.temp_c

    def lanes(self, index) -> Run:
        """The run of some lanes only."""
        gains = None if self.gains is None else self.gains[index]
        streamed = None if self.streamed is None else self.streamed.lanes(index)
        return Run(self.t_s, self.temp_c[:, index], self.duty[:, index], self.target_c, self.start_c,
                   self.disturbances_s, self.tripped[index], gains, self.input_full_scale, streamed)


def _trapezoid(t_s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Integral over axis 0 of samples y (rows, N), trapezoid rule as twin/metrics.py."""
    dt = np.diff(t_s)[:, None]
    return np.sum(dt * (y[1:] + y[:-1]) / 2, axis=0)


def _phase_starts(run: Run) -> np.ndarray:
    """Per sample, the start of its phase: 0 for the heat-up, else the last disturbance before it."""
    edges = np.concatenate(([float(run.t_s[0])], run.disturbances_s))
    return edges[np.searchsorted(edges, run.t_s, side="right") - 1]


# -- metric variants -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Seed000Metrics:
    """Seed 000's metrics, arrays (N,): its ``calculate_metrics`` listing, applied to the rise
    above the start (its model starts at 0) over the heat-up samples.

    overshoot_c = max(y) - sp if above sp else 0; overshoot_pct = 100 overshoot / sp;
    steady_state_error_c = |y[-1] - sp|; settling_time_s = the time of the LAST sample outside
    +-5 % of sp when the response ever exceeds sp, else the last sample's time (so a response that
    never overshoots "settles" at the end of the window: the seed's rule, kept); rise_time_s = the
    time between the first and the last sample inside 10..90 % of sp (NaN if fewer than 2).
    """

    overshoot_c: np.ndarray
    overshoot_pct: np.ndarray
    steady_state_error_c: np.ndarray
    settling_time_s: np.ndarray
    rise_time_s: np.ndarray


def seed000_metrics(t_s: np.ndarray, rise_c: np.ndarray, setpoint_c: float) -> Seed000Metrics:
    """Seed 000's metric definitions on responses rise_c (rows, N) to a setpoint setpoint_c."""
    t = np.asarray(t_s, float) - float(t_s[0])
    y = np.asarray(rise_c, float).reshape(t.size, -1)
    peak = y.max(axis=0)
    overshoot = np.where(peak > setpoint_c, peak - setpoint_c, 0.0)
    outside = np.abs(y - setpoint_c) > SEED000_BAND * setpoint_c
    rows = np.arange(t.size)[:, None]
    last_out = np.where(outside, rows, -1).max(axis=0)
    # the seed indexes time[...][-1]: with no sample outside the band its code raises; 0 here
    settling = np.where(peak > setpoint_c, np.where(last_out >= 0, t[np.maximum(last_out, 0)], 0.0), t[-1])
    inside = (y >= 0.1 * setpoint_c) & (y <= 0.9 * setpoint_c)
    first_in = np.where(inside, rows, t.size).min(axis=0)
    last_in = np.where(inside, rows, -1).max(axis=0)
    rise = np.where(inside.sum(axis=0) > 1, t[np.minimum(last_in, t.size - 1)] - t[np.minimum(first_in, t.size - 1)],
                    np.nan)
    return Seed000Metrics(overshoot, 100.0 * overshoot / setpoint_c, np.abs(y[-1] - setpoint_c), settling, rise)


def heatup_seed000(run: Run) -> Seed000Metrics:
    """Seed 000's metrics of the heat-up phase (the rise above the start temperature)."""
    keep = run.t_s < run.heatup_end_s
    return seed000_metrics(run.t_s[keep], run.temp_c[keep] - run.start_c, run.target_c - run.start_c)


@dataclass(frozen=True)
class Seed002Metrics:
    """Seed 002's table 9/10 quantities, arrays (N,): overshoot in % of the step, peak time,
    settling time ("stable time": after which the error stays inside +-2 % of the step, to the
    end of the heat-up), and after the first disturbance its maximum deviation and recovery
    time into the 2 % error bars (NaN where not settled / no disturbance)."""

    overshoot_pct: np.ndarray
    peak_time_s: np.ndarray
    settling_time_s: np.ndarray
    max_deviation_c: np.ndarray
    recovery_time_s: np.ndarray


def _settled_after(t: np.ndarray, e: np.ndarray, band: float, origin_s: float) -> np.ndarray:
    """Per lane, the time from origin after which |e| <= band (sample times); NaN if out at the end."""
    rows = np.arange(t.size)[:, None]
    last_out = np.where(np.abs(e) > band, rows, -1).max(axis=0)
    after = t[np.minimum(last_out + 1, t.size - 1)] - origin_s
    return np.where(last_out == t.size - 1, np.nan, np.where(last_out < 0, 0.0, after))


def seed002_metrics(run: Run) -> Seed002Metrics:
    """Seed 002's metrics of a run (heat-up, then its first disturbance)."""
    step_c = run.target_c - run.start_c
    band = SEED002_BAND * abs(step_c)
    heat = run.t_s < run.heatup_end_s
    t, e = run.t_s[heat], run.error_c[heat]
    beyond = -np.sign(step_c) * e
    peak_row = beyond.argmax(axis=0)
    overshoot = np.maximum(beyond.max(axis=0), 0.0)
    nan = np.full(run.n, np.nan)
    deviation, recovery = nan, nan
    if run.disturbances_s:
        after = run.t_s >= run.disturbances_s[0]
        end = run.t_s < (run.disturbances_s[1] if len(run.disturbances_s) > 1 else np.inf)
        window = after & end
        deviation = np.abs(run.error_c[window]).max(axis=0)
        recovery = _settled_after(run.t_s[window], run.error_c[window], band, run.disturbances_s[0])
    return Seed002Metrics(100.0 * overshoot / abs(step_c), np.where(overshoot > 0, t[peak_row] - t[0], np.nan),
                          _settled_after(t, e, band, float(t[0])), deviation, recovery)


# -- objectives ------------------------------------------------------------------------------------
def _seed000(weights: tuple[float, float, float, float], squared: bool) -> Callable[[Run], np.ndarray]:
    w_os, w_settle, w_sse, w_gain = weights

    def cost(run: Run) -> np.ndarray:
        if run.gains is None:
            raise ValueError("seed 000's objectives penalise PID gains: tune a PID controller with them")
        m = heatup_seed000(run)
        gains = run.gains ** 2 if squared else run.gains
        return (w_os * m.overshoot_c + w_settle * m.settling_time_s + w_sse * m.steady_state_error_c
                + w_gain * gains.sum(axis=1))

    return cost


def seed002_q(run: Run) -> np.ndarray:
    """Seed 002 equation (17): Q = integral (w1 |e| + w2 u^2 + w3 |e| [overshooting]) dt, u in the
    plant's input units (duty x input_full_scale; seed 002's model takes the duty, scale 1)."""
    w1, w2, w3 = SEED002_W
    e = run.error_c
    overshooting = np.sign(run.target_c - run.start_c) * e < 0
    u = run.duty * run.input_full_scale
    return _trapezoid(run.t_s, w1 * np.abs(e) + w2 * u * u + w3 * np.abs(e) * overshooting)


def itae(run: Run) -> np.ndarray:
    """Integral of (t - t_phase) |e| dt, the clock restarting at each disturbance."""
    since = (run.t_s - _phase_starts(run))[:, None]
    return _trapezoid(run.t_s, since * np.abs(run.error_c))


def iae(run: Run) -> np.ndarray:
    """Integral of |e| dt over the whole run."""
    return _trapezoid(run.t_s, np.abs(run.error_c))


@dataclass(frozen=True)
class HeaterTerms:
    """The parts of the heater objective, arrays (N,): see ``heater_cost``."""

    reach_s: np.ndarray  # time to the band (or the heat-up's length + UNREACHED_S)
    overshoot_c: np.ndarray  # peak beyond the target during the heat-up
    hold_error_c: np.ndarray  # mean |e| from reaching the band to the end (disturbances included)
    chatter: np.ndarray  # mean |duty change| per reading over the same span
    tripped: np.ndarray

    @property
    def cost_s(self) -> np.ndarray:
        return (self.reach_s + OVERSHOOT_S_PER_C * np.maximum(self.overshoot_c - OVERSHOOT_BOUND_C, 0.0)
                + HOLD_S_PER_C * self.hold_error_c + CHATTER_S * np.maximum(self.chatter - CHATTER_BOUND, 0.0)
                + TRIP_S * self.tripped)


def heater_terms(run: Run) -> HeaterTerms:
    """Reach the target fast, overshoot under a bound, hold it, no trip, no duty chatter (from the
    run's trace, or from what the batch streamed: the same rules, ``score_spec``)."""
    if run.streamed is not None:
        return _streamed_terms(run.streamed, run.tripped)
    t, e = run.t_s, run.error_c
    heat = t < run.heatup_end_s
    in_band = (np.abs(e) <= BAND_C) & heat[:, None]
    reached = in_band.any(axis=0)
    first = np.where(reached, in_band.argmax(axis=0), int(np.count_nonzero(heat)) - 1)
    reach_s = t[first] - t[0] + np.where(reached, 0.0, UNREACHED_S)
    beyond = -np.sign(run.target_c - run.start_c) * e[heat]
    overshoot = np.maximum(beyond.max(axis=0), 0.0)
    rows = np.arange(t.size)[:, None]
    holding = rows >= first[None, :]
    count = np.maximum(holding.sum(axis=0), 1)
    hold_error = np.where(holding, np.abs(e), 0.0).sum(axis=0) / count
    steps = np.abs(np.diff(run.duty, axis=0))
    step_hold = holding[1:] & holding[:-1]
    chatter = np.where(step_hold, steps, 0.0).sum(axis=0) / np.maximum(step_hold.sum(axis=0), 1)
    return HeaterTerms(reach_s, overshoot, hold_error, chatter, run.tripped.copy())


def score_spec(target_c: float, start_c: float, heatup_end_s: float, skip_rows: int = 0) -> ScoreSpec:
    """What a batch accumulates for ``heater_terms`` while it runs (no trace kept)."""
    return ScoreSpec(target_c, start_c, heatup_end_s, BAND_C, skip_rows)


def _streamed_terms(totals: ScoreTotals, tripped: np.ndarray) -> HeaterTerms:
    reach_s = totals.holding_from_s - totals.first_s + np.where(totals.reached, 0.0, UNREACHED_S)
    hold_error = totals.abs_error_sum_c / np.maximum(totals.hold_rows, 1)
    chatter = totals.duty_step_sum / np.maximum(totals.hold_rows - 1, 1)
    return HeaterTerms(reach_s, np.maximum(totals.max_beyond_c, 0.0), hold_error, chatter, tripped.copy())


@dataclass(frozen=True)
class Against:
    """The heater objective plus a charge for each member on which a run is worse than a reference beyond
    bounds: beyond_s_per_c x (hold error above hold_bound_c + overshoot above overshoot_bound_c), the bounds
    one per member (lanes member-major, members x N)."""

    hold_bound_c: np.ndarray
    overshoot_bound_c: np.ndarray
    beyond_s_per_c: float

    def __call__(self, run: Run) -> np.ndarray:
        terms = heater_terms(run)
        per_member = run.n // len(self.hold_bound_c)
        hold = np.repeat(self.hold_bound_c, per_member)
        overshoot = np.repeat(self.overshoot_bound_c, per_member)
        beyond = np.maximum(terms.hold_error_c - hold, 0.0) + np.maximum(terms.overshoot_c - overshoot, 0.0)
        return terms.cost_s + self.beyond_s_per_c * beyond


def needs_trace(cost: Callable[[Run], np.ndarray]) -> bool:
    """Whether an objective needs the run's trace (all but the heater objective, plain or ``Against`` a
    reference, which a batch can stream)."""
    return cost is not heater_cost and not isinstance(cost, Against)


def heater_cost(run: Run) -> np.ndarray:
    """The heater objective in seconds:

    reach_s + 30 s/C x max(0, overshoot_c - 3 C) + 100 s/C x hold_error_c
    + 10000 s x max(0, chatter - 0.02) + 10000 s x tripped.
    """
    return heater_terms(run).cost_s


OBJECTIVES: dict[str, tuple[Callable[[Run], np.ndarray], str]] = {
    "heater": (heater_cost, "reach the band fast, overshoot <= 3 C, hold, no trip, no chatter (seconds)"),
    "itae": (itae, "integral of (t - t_phase) |e| dt, per phase (C s^2)"),
    "iae": (iae, "integral of |e| dt (C s)"),
    "seed000_nm": (_seed000(SEED000_NM, squared=True),
                   "seed 000 Nelder-Mead: 10 OS + Ts + 100 SSE + 0.1 (Kp^2 + Ki^2 + Kd^2)"),
    "seed000_pso": (_seed000(SEED000_PSO, squared=False), "seed 000 PSO: 20 OS + 5 Ts + 10 SSE"),
    "seed000_de": (_seed000(SEED000_DE, squared=False),
                   "seed 000 DE: 100 OS + 20 Ts + 50 SSE + 0.1 (Kp + Ki + Kd)"),
    "seed002_q": (seed002_q, "seed 002 eq. (17): integral of (0.999 |e| + 0.001 u^2 + 100 |e| overshooting) dt"),
}


def objective(name: str) -> Callable[[Run], np.ndarray]:
    """The objective called name; ValueError lists the valid ones."""
    if name not in OBJECTIVES:
        raise ValueError(f"unknown objective {name!r}; choose one of: {', '.join(OBJECTIVES)}")
    return OBJECTIVES[name][0]
