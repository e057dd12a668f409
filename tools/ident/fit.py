"""Plant identification from logs: FOPDT, SOPDT and the twin's lumped hotend/bed models fitted to
logged segments by least squares (scipy.optimize), with standard errors and residuals; quick FOPDT
estimates from a step (seed 001's two-point method) and from relay data (Ku, Tu); and the
segments of a log that are worth fitting.

Simulation: the logged duty is held from each sample to the next (zero-order hold) and run
through the twin's own plants on the firmware tick (twin/linear.py ``LinearPlant``, exact for
these linear models; no second integrator). Dead time is whole ticks (1.024 ms); a delay_s between
two whole ticks interpolates the two responses linearly, so the residuals are a smooth function of
delay_s for the optimiser.

Uncertainty: standard errors are sqrt(diag((J^T J)^-1) s^2), J the Jacobian of the residuals at
the optimum and s^2 = (sum of squared residuals) / (n - p). They hold for independent residuals.
Real logs' residuals are correlated (model error, quantised readings, a 1 Hz pwm), so read them as
lower bounds, and compare fits of different segments for the real spread.

Heater power: a log fixes the heating rate P/C and the rise at full power P/A, not the wattage,
which is rarely stated. The lumped models hold power_w fixed (Marlin's default 40 W unless given)
and fit C, A and R: with the real wattage P', C and A scale by P'/P. ``FitResult.derived()`` gives
the power-free numbers.

Heat loss: the lumped models' loss is linear (Marlin's MPC model) unless ``loss`` asks for the
radiation-like term too (an effective area at emissivity 1, twin/plants.py ``Lumped``), fitted from
the linear fit's values; "auto" keeps whichever has the lower AIC (``fit_losses``). A radiating
plant is simulated by ``radiating_response``.

Tuning: a fitted model's FOPDT equivalent (the two-point method on its step response) plus the
control loop's own delay gives PID gains by the AMIGO rule, and its ultimate point (Ku, Tu), what
an ideal relay autotune would find; relay_fopdt turns a logged relay result back into a FOPDT.

Inputs: duty is 0..1 of full power. Open-loop segments (heat-ups at full power, pulse tests,
multi-level runs) are the best data. In closed-loop segments the duty is what the controller set.
Klipper Stats log the last pwm *sent* to the MCU: Klipper holds back a change under 5 % of
max_power until its next resend, 2.1 to 3.75 s later depending on the version
(firmware_port/klipper/heater.py), and the 1 Hz line samples a 0.3 s control signal. That value
is the input here all the same; the residuals carry its error.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.optimize

from firmware_port.klipper.heater import PID_PARAM_BASE
from tools.logs import HeaterSeries, HeattestLog, Log, M303Log, PlainLog, StatsLog
from tools.ident.relay_trace import command_target_c, estimate_target_c, switch_instants
from twin.linear import SENSOR, TICK_S, TickModel
from twin.plants import (
    MPC_HEATER_POWER_W,
    ONION_CARTRIDGE_HEAT_CAPACITY_J_K,
    V6_BLOCK_AREA_M2,
    Lumped,
    Plant,
    Spec,
    TransferFunction,
)

MODELS = ("fopdt", "sopdt", "two_node", "three_node")
FITTED = {  # the parameters each model fits, besides initial_c, and ambient_c when it is not given
    "fopdt": ("gain_c", "time_constant_s", "delay_s"),
    "sopdt": ("gain_c", "lag1_s", "lag2_s", "delay_s"),
    "two_node": ("block_heat_capacity_j_k", "sensor_responsiveness_per_s", "ambient_xfer_w_k"),
    "three_node": ("block_heat_capacity_j_k", "cartridge_xfer_w_k", "sensor_responsiveness_per_s",
                   "ambient_xfer_w_k"),
}
HELD = {  # held fixed unless given: the log cannot tell them apart from the fitted ones
    "fopdt": {},
    "sopdt": {},
    "two_node": {"power_w": MPC_HEATER_POWER_W},
    # the fit is flat in the cartridge's capacity (python -m tools.validation.plant_check --fit refits 1..8 J/K)
    "three_node": {"power_w": MPC_HEATER_POWER_W, "cartridge_heat_capacity_j_k": ONION_CARTRIDGE_HEAT_CAPACITY_J_K},
}
LUMPED_MODELS = ("two_node", "three_node")
# The heat loss of the lumped models: "linear" A (Tb - Ta) alone; "radiating" adds Lumped's radiation
# term sigma eps area (Tb^4 - Ta^4) at emissivity 1, fitting the effective area; "auto" fits both
# and keeps the one of lower AIC (``information_criterion``).
LOSSES = ("linear", "radiating", "auto")
RADIATING_PARAM = "radiating_area_m2"
RADIATING_EMISSIVITY = 1.0  # held: the area absorbs it (emissivity times the onionheater block's own
# 14.7 cm^2 wanted 2.7 > 1, more than the block radiates: the term also stands for the heat break,
# the nozzle and convection's own rise with temperature, python -m tools.validation.plant_check --fit)
RADIATING_START_M2 = 2 * V6_BLOCK_AREA_M2  # twice an E3D V6 block's surface
# Up to 100 cm^2: about seven V6 blocks, more than a whole hot end's surface. From 0.01 cm^2: at 200 C
# a conductance of 1.5e-5 W/K, nothing beside a hot end's linear loss (0.07 W/K and up); the area is
# fitted as its logarithm, which on a plant without the term would run towards 0 for ever.
RADIATING_BOUNDS_M2 = (1e-6, 0.01)
LINEAR_PARAMS = ("ambient_c", "initial_c", "delay_s")  # fitted as they are; the others as their logarithms
LOG_X_SCALE = 0.1  # least_squares x_scale of a logarithm (10 % steps); 1 C or 1 s for the linear ones
MAX_EVALUATIONS = 400  # residual evaluations: a segment that has not converged by then holds too little
UNDETERMINED = 1e-9  # a Jacobian column this small against the largest: the residuals ignore that parameter
MAX_LOG = 700.0  # exp() of a logarithm beyond this overflows: the optimiser is exploring, clip it

# Smith's two-point method (seed 001 eq. (8), which attributes it to Cohen-Coon): T = 1.5 (t2 - t1),
# delay = t2 - T, with t1, t2 the times to these fractions of the step's rise. Exact for a FOPDT;
# the seed rounds the first fraction to 0.28.
TWO_POINT_FRACTIONS = (1.0 - math.exp(-1.0 / 3.0), 1.0 - math.exp(-1.0))

# Segments of a log
SATURATION_TOL = 0.0005  # Klipper prints pwm with 3 decimals: at max_power within this
MIN_HEATUP_S = 10.0  # a run at max_power this long starts a heat-up (shorter ones are PID bumps)
HOLD_AFTER_S = 300.0  # a segment ends this long after its heat-up (or its start): the hold, before a print's load
MIN_SAMPLES = 20
M303_MIN_SAMPLES = 12  # a relay trace: three 10 s cycles of 2 s status lines at least
M303_STATUS_PERIOD_S = 2.0  # Marlin reports every 2 s during M303 (hardware_logs README D)
M303_MAX_LINE_STEP = 7  # bias, Ku/Tu, rule and Kp/Ki/Kd lines between two reports; more: a gap
MAX_GUESS_DELAY_S = 60.0  # the start values try dead times up to this
AMBIENT_SLACK_SIGMAS = 4.0  # initial_c within this many noise sigmas of the first reading, ambient_c below the lowest
READING_STEP_C = 0.25  # plus the coarsest reading step of the logs here (the onionheater's thermocouple)
AMBIENT_BELOW_C = 30.0  # and ambient_c above the lowest reading minus this (a heat-up may start warm)
MAX_SENSOR_RESPONSIVENESS_PER_S = 10.0  # a sensor lag under 0.1 s: beyond every log here (0.3 s samples at best)

# Tuning: the PID loop's own delay on top of the plant's. Klipper applies a pwm 0.3 s after the
# sample it answers (pwm_delay) and samples every 0.3 s (half a period on average); Marlin's
# 0.164 s control period is shorter, so this errs on the safe side for it.
CONTROL_DELAY_S = 0.3 + 0.3 / 2
PID_SCALE = PID_PARAM_BASE  # gains per C on 0..255: Klipper's PID_PARAM_BASE, Marlin's PID_MAX output range
STEP_RESPONSE_POINTS = 20000  # the grid of a model's step response for its FOPDT equivalent
RADIATING_STEP_POINTS = 2000  # a radiating model's: a matrix exponential per point (0.4 % of a time constant each)


class Fopdt(NamedTuple):
    """First order plus dead time: gain_c (C of rise per unit of input) e^(-delay_s s) / (time_constant_s s + 1)."""

    gain_c: float
    time_constant_s: float
    delay_s: float


class Segment(NamedTuple):
    """A stretch of a log to fit: sample instants, readings, and the duty held from each sample to the next."""

    label: str
    t_s: np.ndarray
    temp_c: np.ndarray
    duty: np.ndarray  # 0..1 of full power
    fan: float = 0.0  # part fan 0..1 (the lumped models' fan_ambient_xfer_w_k)
    note: str = ""  # what the input is: open loop, closed loop, relay
    full_power_s: float = 0.0  # time at max_power: the open-loop part
    cools_at_full_power: bool = False  # the reading fell while at max_power: the heater did not heat
    observed: np.ndarray | None = None  # False at inserted samples (relay switch instants): not compared
    target_c: float = math.nan  # an M303 relay's target


def default_segment(segments: Sequence[Segment]) -> int:
    """The first segment with at least half the longest time at max_power (the most open-loop data),
    among those where full power heats."""
    usable = [seg for seg in segments if not seg.cools_at_full_power] or list(segments)
    most_s = max(seg.full_power_s for seg in usable)
    return next(i for i, seg in enumerate(segments) if seg in usable and seg.full_power_s >= 0.5 * most_s)


class NotFittable(ValueError):
    """A log, or a part of one, that holds no temperature-and-duty series to fit; says why."""


@dataclass(frozen=True)
class Estimate:
    """What least_squares_fit returns: the values, their standard errors and the residuals (model - log)."""

    values: dict[str, float]
    std_errors: dict[str, float]
    residuals_c: np.ndarray

    @property
    def rmse_c(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals_c))))

    @property
    def aic(self) -> float:
        return information_criterion(self.residuals_c, len(self.values))


def information_criterion(residuals_c: np.ndarray, n_params: int) -> float:
    """Akaike's information criterion of a least-squares fit, n ln(SSE / n) + 2 k (Akaike 1974, "A new
    look at the statistical model identification", IEEE TAC 19:716-723, for Gaussian residuals):
    lower is better; a parameter must buy more than a factor e^(2/n) of the squared error."""
    n = len(residuals_c)
    return float(n * math.log(max(float(np.sum(np.square(residuals_c))), 1e-300) / n) + 2 * n_params)


# --- the fitter ----------------------------------------------------------------------------------


def least_squares_fit(residuals: Callable[[dict[str, float]], np.ndarray], start: dict[str, float],
                      linear: Sequence[str] = LINEAR_PARAMS,
                      bounds: dict[str, tuple[float, float]] | None = None) -> Estimate:
    """Minimise sum(residuals(params)^2) from start, every parameter not in ``linear`` as its
    logarithm (positive, relative steps), within optional bounds (low, high) per parameter;
    standard errors from the Jacobian at the optimum (NaN at a bound, infinite if undetermined)."""
    names = list(start)
    is_log = np.array([name not in linear for name in names])

    def params(z: np.ndarray) -> dict[str, float]:
        values = np.where(is_log, np.exp(np.where(is_log, np.minimum(z, MAX_LOG), 0.0)), z)
        return dict(zip(names, values.tolist()))

    def internal(values) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return np.array([np.log(max(v, 0.0)) if log else v for v, log in zip(values, is_log)], dtype=float)

    limits = [(bounds or {}).get(name, (-math.inf, math.inf)) for name in names]
    sol = scipy.optimize.least_squares(lambda z: residuals(params(z)), internal(start.values()),
                                       x_scale=np.where(is_log, LOG_X_SCALE, 1.0), max_nfev=MAX_EVALUATIONS,
                                       bounds=(internal([lo for lo, _ in limits]), internal([hi for _, hi in limits])))
    values = params(sol.x)
    # A parameter stopped at a bound gets no standard error (NaN), one the residuals do not depend on
    # an infinite one; the others' come from their own columns of the Jacobian.
    column = np.linalg.norm(sol.jac, axis=0)
    free = (sol.active_mask == 0) & (column > UNDETERMINED * column.max())
    sigma_z = np.where(sol.active_mask == 0, np.inf, np.nan)
    jac = sol.jac[:, free]
    try:
        cov = np.linalg.inv(jac.T @ jac) * float(sol.fun @ sol.fun) / max(len(sol.fun) - free.sum(), 1)
        sigma_z[free] = np.sqrt(np.abs(np.diag(cov)))
    except np.linalg.LinAlgError:  # the free ones are not determined apart
        pass
    std = {n: float(values[n] * s if log else s) for n, s, log in zip(names, sigma_z, is_log)}  # delta method
    return Estimate(values, std, sol.fun.copy())


def zoh_response(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The plant's sensor at the instants t_s (from t_s[0]), its heater at duty[i] from t_s[i] to
    t_s[i + 1]; instants on the tick grid (1.024 ms). A radiating plant: ``radiating_response``."""
    if not plant.linear:
        return radiating_response(plant, t_s, duty)
    ticks = np.rint((t_s - t_s[0]) / TICK_S).astype(int)
    out = np.empty(len(t_s))
    out[0] = plant.temps_c()[SENSOR]
    for i, n in enumerate(np.diff(ticks)):
        plant.advance(np.full(n, duty[i]))
        plant.relinearise()
        out[i + 1] = plant.temps_c()[SENSOR]
    return out


def radiating_response(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """A radiating lumped plant's sensor at the instants t_s, from its state now: over each sample
    interval the plant's own model (``Lumped.lti``) linearised at the block's temperature at the
    interval's start (the secant radiation conductance, docs/plants.md "Radiation"), stepped exactly
    for that interval's duty by one matrix exponential of the model augmented with its constant input.

    The engine relinearises the same model between its runs (at most 160 ticks) in 0.5 C bins, each
    bin a discretisation of its own; per sample, unbinned, the residuals are smooth in the radiation
    parameter and a fit does not rebuild a tick model for every bin (about 5 s against 0.05 s per
    evaluation on the onionheater pulse)."""
    spec = plant.spec
    x = plant.x.copy()
    n = len(x)
    out = np.empty(len(t_s))
    out[0] = plant.temps_c()[SENSOR]
    augmented = np.zeros((n + 1, n + 1))
    for i, step_s in enumerate(np.diff(t_s)):
        lti = spec.lti(spec.conditions(plant.fan, plant.flow_mm_s, plant.ambient_c, float(x[0]))._replace(
            block_bin_c=float(x[0])))
        augmented[:n, :n] = lti.a
        augmented[:n, n] = lti.b * duty[i] + lti.e @ plant.d
        x = (scipy.linalg.expm(augmented * step_s) @ np.r_[x, 1.0])[:n]
        out[i + 1] = lti.c[SENSOR] @ x
    plant.x = x
    return out


def fit_plants(make: Callable[..., Plant], start: dict[str, float], segments: Sequence[Segment],
               bounds: dict[str, tuple[float, float]] | None = None) -> Estimate:
    """Fit the parameters start names (within optional bounds) over segments at once;
    ``make(segment, **params)`` builds the plant for one segment from what the segment declares
    (its ambient, start state and fan)."""
    return least_squares_fit(lambda p: np.concatenate(
        [zoh_response(make(seg, **p), seg.t_s, seg.duty) - seg.temp_c for seg in segments]), start, bounds=bounds)


# --- the models ----------------------------------------------------------------------------------


def model_spec(model: str, params: dict[str, float]) -> Spec:
    """The twin's plant for a model's parameters (ambient_c aside): TransferFunction or Lumped."""
    p = params
    if model == "fopdt":
        return TransferFunction(p["gain_c"], 1.0, lag1_s=p["time_constant_s"], delay_s=p["delay_s"])
    if model == "sopdt":
        return TransferFunction(p["gain_c"], 1.0, lag1_s=p["lag1_s"], lag2_s=p["lag2_s"], delay_s=p["delay_s"])
    names = {f.name for f in dataclasses.fields(Lumped)}
    lumped = {k: v for k, v in p.items() if k in names}
    lumped.setdefault("fan_ambient_xfer_w_k", p["ambient_xfer_w_k"])  # logs carry no part-fan speed
    return Lumped(**lumped)


def _response(model: str, values: dict[str, float], t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The model's sensor at t_s for the zero-order-hold duty, from initial_c (every node, or the
    equilibrium holding it), the delay interpolated between whole ticks."""
    spec = model_spec(model, values)

    def run(s: Spec) -> np.ndarray:
        return zoh_response(Plant(model, s, values["ambient_c"], values["initial_c"]), t_s, duty)

    if not isinstance(spec, TransferFunction):
        return run(spec)
    whole, frac = divmod(spec.delay_s / TICK_S, 1.0)
    early = run(dataclasses.replace(spec, delay_s=whole * TICK_S))
    if not frac:
        return early
    return (1.0 - frac) * early + frac * run(dataclasses.replace(spec, delay_s=(whole + 1.0) * TICK_S))


@dataclass(frozen=True)
class FitResult:
    """A model fitted to a segment: parameters (units in their names) with standard errors, the
    values held fixed, and the residuals (model - log) at the segment's samples. initial_c is the
    temperature every node starts at (for the transfer functions: the equilibrium that holds it)."""

    model: str
    params: dict[str, float]  # fitted
    std_errors: dict[str, float]  # NaN: stopped at a bound; inf: the segment does not determine it
    fixed: dict[str, float]  # held: power_w, ambient_c when given, ...
    residuals_c: np.ndarray
    loss: str = "linear"  # the lumped models' heat loss: "linear" or "radiating" (LOSSES)

    @property
    def values(self) -> dict[str, float]:
        return {**self.fixed, **self.params}

    @property
    def rmse_c(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals_c))))

    @property
    def max_abs_residual_c(self) -> float:
        return float(np.max(np.abs(self.residuals_c)))

    @property
    def n_samples(self) -> int:
        return len(self.residuals_c)

    def spec(self) -> Spec:
        """The fitted plant as a twin/plants.py spec (for twin.plants.Plant)."""
        return model_spec(self.model, self.values)

    def simulate(self, t_s: np.ndarray, duty: np.ndarray, initial_c: float | None = None) -> np.ndarray:
        """The fitted model's reading at t_s for a zero-order-hold duty, from initial_c (default: the fit's)."""
        values = self.values if initial_c is None else {**self.values, "initial_c": initial_c}
        return _response(self.model, values, np.asarray(t_s, float), np.asarray(duty, float))

    def derived(self) -> dict[str, float]:
        """Numbers that do not depend on the assumed power: for the lumped models the heating rate
        at full power (C/s), the rise at full power (C), the loss time constant and the sensor lag.
        With the radiating loss the rise solves P = (A + h(T)) (T - Ta), h the radiation's secant
        conductance (twin/plants.py ``Lumped.radiation_w_k``), and the time constant is the one near
        ambient, where h is 4 sigma eps area Ta^3: both scale with P like C, A and the area."""
        v = self.values
        spec = self.spec()
        if not isinstance(spec, Lumped):
            return {}
        capacity_j_k = v["block_heat_capacity_j_k"] + v.get("cartridge_heat_capacity_j_k", 0.0)
        ambient_c, power_w, linear_w_k = v["ambient_c"], v["power_w"], v["ambient_xfer_w_k"]
        near_ambient_w_k = linear_w_k + spec.radiation_w_k(ambient_c, ambient_c)
        rise_c = power_w / near_ambient_w_k  # the secant conductance only grows with temperature: an upper bound
        if not spec.linear:
            rise_c = scipy.optimize.brentq(
                lambda r: (linear_w_k + spec.radiation_w_k(ambient_c + r, ambient_c)) * r - power_w, 0.0, rise_c)
        return {"heating_rate_c_s": power_w / capacity_j_k,
                "rise_at_full_power_c": float(rise_c),
                "loss_time_constant_s": capacity_j_k / near_ambient_w_k,
                "sensor_lag_s": 1.0 / v["sensor_responsiveness_per_s"]}


def _check_series(t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, n_params: int) -> None:
    if not (len(t_s) == len(temp_c) == len(duty)):
        raise ValueError(f"t_s, temp_c and duty differ in length ({len(t_s)}, {len(temp_c)}, {len(duty)})")
    if len(t_s) <= n_params + 1:
        raise ValueError(f"{len(t_s)} samples: too few to fit {n_params} parameters")
    if not (np.all(np.isfinite(t_s)) and np.all(np.isfinite(temp_c)) and np.all(np.isfinite(duty))):
        raise ValueError("t_s, temp_c and duty must be finite")
    if np.any(np.diff(t_s) <= 0):
        raise ValueError("t_s must increase")
    if np.any(duty < 0) or np.any(duty > 1):
        raise ValueError("duty must be within 0..1 of full power")


def reading_noise_c(temp_c: np.ndarray) -> float:
    """The readings' noise (standard deviation) from their second differences, robustly (MAD)."""
    d2 = np.diff(temp_c, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0)) if d2.size else 0.0


def _first_order_guess(t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, ambient_c: float) -> Fopdt:
    """Start values: dT/dt = (K u(t - L) - (T - ambient)) / tau by linear least squares on the
    sample-to-sample slopes (equation error), the duty 0 before the segment, for each dead time of
    whole samples; the best one."""
    dt = np.diff(t_s)
    slope = np.diff(temp_c) / dt
    rise = temp_c[:-1] - ambient_c
    best = None
    for shift in range(min(len(dt) // 4, int(MAX_GUESS_DELAY_S / np.median(dt))) + 1):
        x = np.column_stack((np.r_[np.zeros(shift), duty[: len(dt) - shift]], rise))
        coef, *_ = np.linalg.lstsq(x, slope, rcond=None)
        sse = float(np.sum(np.square(x @ coef - slope)))
        if coef[1] < 0 and coef[0] > 0 and (best is None or sse < best[0]):
            best = (sse, coef, float(t_s[shift] - t_s[0]))
    span_s = float(t_s[-1] - t_s[0])
    if best is None:  # no first-order shape in the slopes: rough numbers from the record itself
        return Fopdt(2.0 * max(float(np.ptp(temp_c)), 1.0) / max(float(duty.max()), 0.05), span_s / 3.0, 0.01 * span_s)
    _, (b, a), delay_s = best
    return Fopdt(float(-b / a), float(-1.0 / a), max(delay_s, float(np.median(dt)) / 2.0))


def _start_values(model: str, guess: Fopdt, held: dict[str, float]) -> dict[str, float]:
    k, tau, delay = guess
    if model == "fopdt":
        return {"gain_c": k, "time_constant_s": tau, "delay_s": delay}
    if model == "sopdt":
        return {"gain_c": k, "lag1_s": tau, "lag2_s": delay / 2.0, "delay_s": delay / 2.0}
    loss_w_k = held["power_w"] / k
    start = {"block_heat_capacity_j_k": loss_w_k * tau, "ambient_xfer_w_k": loss_w_k,
             "sensor_responsiveness_per_s": min(1.0 / delay, MAX_SENSOR_RESPONSIVENESS_PER_S / 2)}
    if model == "three_node":  # the lag split between the cartridge contact and the sensor
        start["sensor_responsiveness_per_s"] = min(2.0 / delay, MAX_SENSOR_RESPONSIVENESS_PER_S / 2)
        start["cartridge_xfer_w_k"] = 2.0 * held["cartridge_heat_capacity_j_k"] / delay
    return {name: start[name] for name in FITTED[model]}


def _check_loss(model: str, loss: str) -> None:
    """ValueError for an unknown model or loss, or a nonlinear loss on a transfer function."""
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; valid: {', '.join(MODELS)}")
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; valid: {', '.join(LOSSES)}")
    if loss != "linear" and model not in LUMPED_MODELS:
        raise ValueError(f"loss {loss!r} needs a lumped model ({', '.join(LUMPED_MODELS)}): {model} has no heat-loss "
                         "term to make nonlinear")


def fit_model(model: str, t_s, temp_c, duty, ambient_c: float | None = None, *, power_w: float | None = None,
              fixed: dict[str, float] | None = None, start: dict[str, float] | None = None,
              observed: np.ndarray | None = None, loss: str = "linear") -> FitResult:
    """Fit a model to one segment: readings temp_c at t_s under the duty (0..1) held from each sample.

    model: "fopdt" (gain_c, time_constant_s, delay_s), "sopdt" (two lags, lag1_s >= lag2_s),
    "two_node" (Marlin's MPC model: block heat capacity, sensor responsiveness, ambient loss) or
    "three_node" (plus the heater cartridge's contact to the block: its lag and the sensor's can
    trade places, two near-equal optima); every one also fits initial_c, the temperature it starts
    at, near the first reading (one reading is noisy). ambient_c None: fitted too, within 30 C below
    the lowest reading and, give or take the readings' noise, not above it. power_w (lumped models,
    default 40 W) and other values in ``fixed`` are held; ``start`` overrides start values.
    observed (bool per sample, default all): the samples whose readings are compared; the others
    only carry a duty change (a relay's reconstructed switch instant).
    loss (lumped models): "linear", "radiating" (plus radiating_area_m2 at emissivity 1, within
    RADIATING_BOUNDS_M2) or "auto" (both, the lower AIC kept: ``fit_losses``).
    ValueError for an unusable series or option.
    """
    _check_loss(model, loss)
    if loss == "linear":
        return _fit_loss(model, "linear", t_s, temp_c, duty, ambient_c, power_w=power_w, fixed=fixed, start=start,
                         observed=observed)
    choice = fit_losses(model, t_s, temp_c, duty, ambient_c, power_w=power_w, fixed=fixed, start=start,
                        observed=observed)
    return choice.fits[choice.kept if loss == "auto" else "radiating"]


def _fit_loss(model: str, loss: str, t_s, temp_c, duty, ambient_c: float | None, *, power_w: float | None = None,
              fixed: dict[str, float] | None = None, start: dict[str, float] | None = None,
              observed: np.ndarray | None = None) -> FitResult:
    """``fit_model`` with one loss, "linear" or "radiating", from start values guessed or given."""
    radiating = loss == "radiating"
    fitted = FITTED[model] + ((RADIATING_PARAM,) if radiating else ())
    t_s, temp_c, duty = (np.asarray(a, dtype=float) for a in (t_s, temp_c, duty))
    _check_series(t_s, temp_c, duty, len(fitted) + 1 + (ambient_c is None))
    held = {**HELD[model], **({"emissivity": RADIATING_EMISSIVITY} if radiating else {})}
    unknown = (set(fixed or {}) | set(start or {})) - {*fitted, *held, "ambient_c", "initial_c"}
    if unknown:
        raise ValueError(f"{model} ({loss} loss) has no parameter {', '.join(sorted(unknown))}")
    held.update(fixed or {})
    if power_w is not None:
        held["power_w"] = float(power_w)
    if ambient_c is not None:
        held["ambient_c"] = float(ambient_c)
    # The start is the first reading and ambient at most the lowest (a heater cannot cool below it),
    # both give or take the readings' noise and resolution.
    seen = np.ones(len(t_s), bool) if observed is None else np.asarray(observed, bool)
    slack_c = AMBIENT_SLACK_SIGMAS * reading_noise_c(temp_c[seen]) + READING_STEP_C
    ambient_start_c = float(ambient_c if ambient_c is not None else temp_c.min())
    guess = _first_order_guess(t_s, temp_c, duty, ambient_start_c)
    first = {**_start_values(model, guess, held), **({RADIATING_PARAM: RADIATING_START_M2} if radiating else {}),
             "initial_c": float(temp_c[0]), **({} if ambient_c is not None else {"ambient_c": ambient_start_c}),
             **(start or {})}
    first = {k: v for k, v in first.items() if k not in held}
    est = least_squares_fit(lambda p: (_response(model, {**held, **p}, t_s, duty) - temp_c)[seen], first,
                            bounds={"ambient_c": (temp_c.min() - AMBIENT_BELOW_C, temp_c.min() + slack_c),
                                    "initial_c": (temp_c[0] - slack_c, temp_c[0] + slack_c),
                                    "delay_s": (0.0, math.inf),
                                    "sensor_responsiveness_per_s": (0.0, MAX_SENSOR_RESPONSIVENESS_PER_S),
                                    RADIATING_PARAM: RADIATING_BOUNDS_M2})
    params, std = est.values, est.std_errors
    if model == "sopdt" and params["lag2_s"] > params["lag1_s"]:  # the two lags are interchangeable
        for d in (params, std):
            d["lag1_s"], d["lag2_s"] = d["lag2_s"], d["lag1_s"]
    return FitResult(model, params, std, held, est.residuals_c, loss)


class LossChoice(NamedTuple):
    """Both losses fitted to one segment, by loss name, and the name of the one of lower AIC."""

    fits: dict[str, FitResult]
    kept: str


def fit_losses(model: str, t_s, temp_c, duty, ambient_c: float | None = None, *,
               start: dict[str, float] | None = None, **options) -> LossChoice:
    """A lumped model fitted with the linear loss, then with the radiating one from the linear fit's
    values (a nested model: the radiating fit starts where the linear one ended, plus
    RADIATING_START_M2; ``start`` overrides both), ``fit_model``'s other options as given; kept: the
    lower AIC, which charges the radiating fit its extra parameter (``aic``)."""
    _check_loss(model, "auto")
    linear = _fit_loss(model, "linear", t_s, temp_c, duty, ambient_c,
                       start={k: v for k, v in (start or {}).items() if k != RADIATING_PARAM}, **options)
    radiating = _fit_loss(model, "radiating", t_s, temp_c, duty, ambient_c,
                          start={**linear.params, RADIATING_PARAM: RADIATING_START_M2, **(start or {})}, **options)
    fits = {"linear": linear, "radiating": radiating}
    return LossChoice(fits, min(fits, key=lambda name: aic(fits[name])))


def aic(result: FitResult) -> float:
    """``information_criterion`` of a fitted model: its residuals and its fitted parameters."""
    return information_criterion(result.residuals_c, len(result.params))


def best_fit(models: Sequence[str], seg: Segment, ambient_c: float | None, power_w: float | None) -> FitResult:
    """The model of lowest AIC among ``models`` fitted to one segment (power_w for the lumped ones)."""
    fits = [fit_model(m, seg.t_s, seg.temp_c, seg.duty, ambient_c, observed=seg.observed,
                      power_w=power_w if m in ("two_node", "three_node") else None) for m in models]
    return min(fits, key=aic)


# --- quick estimates and tuning ------------------------------------------------------------------


def _crossing_s(t_s: np.ndarray, temp_c: np.ndarray, level_c: float, rising: bool) -> float:
    """First time temp_c reaches level_c (from below if rising, else from above), interpolated."""
    sign = 1.0 if rising else -1.0
    y, level = sign * temp_c, sign * level_c
    reached = y >= level
    if not reached.any():
        raise ValueError(f"the response never reaches {level_c:.3g}")
    i = int(np.argmax(reached))
    return float(t_s[0]) if i == 0 else float(np.interp(level, y[i - 1 : i + 1], t_s[i - 1 : i + 1]))


def two_point_fopdt(t_s, temp_c, step_size: float, final_c: float | None = None) -> Fopdt:
    """Seed 001's two-point method on a step response: the step at t_s[0] from the reading
    temp_c[0] to final_c (default: the last reading, so the response must have settled).

    gain = rise / step_size; with t1, t2 the times to 28.3 % and 63.2 % of the rise,
    T = 1.5 (t2 - t1) and delay = 1.5 (t1 - t2 / 3) (seed 001, eq. (8); Smith's method).
    """
    t_s, temp_c = np.asarray(t_s, float), np.asarray(temp_c, float)
    final = float(temp_c[-1] if final_c is None else final_c)
    rise = final - float(temp_c[0])
    if not rise or not step_size:
        raise ValueError("a step response needs a non-zero step and a non-zero rise")
    t1, t2 = (_crossing_s(t_s, temp_c, temp_c[0] + f * rise, rise > 0) - t_s[0] for f in TWO_POINT_FRACTIONS)
    return Fopdt(rise / step_size, float(1.5 * (t2 - t1)), float(1.5 * (t1 - t2 / 3.0)))


def ultimate_point(fopdt: Fopdt) -> tuple[float, float]:
    """(Ku, Tu) of a FOPDT: the proportional gain (input per C) and the period at which a P
    controller would hold a steady oscillation: atan(w T) + w L = pi, Ku = sqrt(1 + (w T)^2) / K.

    The closed form for a FOPDT (twin-fit, seed 001); tools.tuning.ultimate.ultimate_point does any
    model from its frequency response."""
    k, tau, delay = fopdt
    if delay <= 0 or k <= 0 or tau < 0:
        raise ValueError(f"no ultimate point for {fopdt}: needs a positive gain and dead time")
    w = scipy.optimize.brentq(lambda w: math.atan(w * tau) + w * delay - math.pi, 1e-12, math.pi / delay)
    return math.hypot(1.0, w * tau) / k, 2.0 * math.pi / w


def relay_fopdt(ku: float, tu_s: float, gain_c: float) -> Fopdt:
    """A FOPDT through a relay test's ultimate point (Ku, Tu) with a known static gain: the inverse
    of ultimate_point (Astrom and Hagglund, PID Controllers: Theory, Design, and Tuning, 1995:
    a relay finds one point of the frequency response; K fixes the rest of a FOPDT).

    w = 2 pi / Tu, T = sqrt((K Ku)^2 - 1) / w, L = (pi - atan(w T)) / w. ku is the textbook
    describing-function gain 4 d / (pi a), duty per C (d the relay's half swing in duty, a half the
    temperature's peak-to-peak): Marlin's M303 prints it on 0..255 (divide by 255); Klipper's
    PID_CALIBRATE prints twice it (it takes the full swing 0..max_power for d). gain_c: C of rise
    per unit duty, e.g. (target - ambient) / mean duty at the target.
    """
    if ku <= 0 or tu_s <= 0 or gain_c * ku <= 1.0:
        raise ValueError(f"no FOPDT through Ku={ku:g}, Tu={tu_s:g} with gain {gain_c:g}: needs K Ku > 1")
    w = 2.0 * math.pi / tu_s
    tau = math.sqrt((gain_c * ku) ** 2 - 1.0) / w
    return Fopdt(gain_c, tau, (math.pi - math.atan(w * tau)) / w)


def fopdt_equivalent(result: FitResult) -> Fopdt:
    """The fitted model as a FOPDT: itself, or the two-point method on its unit step response (exact
    zero-order-hold steps of the model on a grid up to 8 of its slowest time constants; a radiating
    model's own nonlinear step from ambient, ``radiating_response``, time constants taken at ambient,
    where its loss is least)."""
    if result.model == "fopdt":
        return Fopdt(*(result.params[name] for name in FITTED["fopdt"]))
    spec = result.spec()
    ambient_c = result.values.get("ambient_c", 0.0)
    lti = spec.lti(spec.conditions(0.0, 0.0, ambient_c, ambient_c))
    slowest_s = 1.0 / float(np.min(np.abs(np.linalg.eigvals(lti.a).real)))
    if spec.linear:
        gain_c = float(-(lti.c[SENSOR] @ np.linalg.solve(lti.a, lti.b)))
        step_s = 8.0 * slowest_s / STEP_RESPONSE_POINTS
        step_c = TickModel(lti, step_s).u_steps(STEP_RESPONSE_POINTS) @ lti.c[SENSOR]
    else:
        gain_c = result.derived()["rise_at_full_power_c"]
        step_s = 8.0 * slowest_s / RADIATING_STEP_POINTS
        grid_s = step_s * np.arange(RADIATING_STEP_POINTS + 1)
        step_c = radiating_response(Plant(result.model, spec, ambient_c, ambient_c), grid_s,
                                    np.ones(len(grid_s))) - ambient_c
    t_s = spec.delay_ticks * TICK_S + step_s * np.arange(len(step_c))
    k, tau, delay = two_point_fopdt(np.r_[0.0, t_s], np.r_[0.0, step_c], 1.0, final_c=gain_c)
    return Fopdt(k, tau, max(delay, 0.0))  # a lag too short for the step's shape reads as a few ms either way


# --- what a log offers ---------------------------------------------------------------------------


def _segment(label: str, t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, max_power: float, between: str,
             extra: str = "") -> Segment:
    """A Segment noting its seconds at max_power, off and in between (duty held from each sample to the next)."""
    held_s = np.diff(t_s)
    u = duty[:-1]
    full = u >= max_power - SATURATION_TOL
    parts = [(f"at max_power {max_power:g}" if max_power < 1 else "full power", held_s[full].sum()),
             ("off", held_s[u == 0].sum()), (f"in between ({between})", held_s[~full & (u > 0)].sum())]
    cools = bool(full.any() and np.diff(temp_c)[full].sum() < 0)
    note = (", ".join(f"{what} {s:.0f} s" for what, s in parts if s) + extra
            + ("; the reading FALLS at full power: the heater did not heat (a fault?)" if cools else ""))
    return Segment(f"{label}{t_s[0]:.1f}..{t_s[-1]:.1f} s", t_s, temp_c, duty, note=note,
                   full_power_s=float(held_s[full].sum()), cools_at_full_power=cools)


def split_heatups(label: str, t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, max_power: float = 1.0,
                  between: str = "closed loop", target_c: np.ndarray | None = None) -> list[Segment]:
    """Segments of one gap-free series: from the heater's first turn-on and from each heat-up (a run at
    max_power of MIN_HEATUP_S or more) to the next, each cut HOLD_AFTER_S after its heat-up (or
    its start), and at the first change of target_c after it (a print starting changes the load);
    those of fewer than MIN_SAMPLES samples are left out."""
    full = duty >= max_power - SATURATION_TOL
    on = np.flatnonzero(duty > 0)
    if not on.size:
        return []
    last = len(t_s) - 1
    runs: list[list[int]] = []  # [start, end) at max_power, dips shorter than MIN_HEATUP_S bridged
    starts, ends = np.flatnonzero(full & ~np.r_[False, full[:-1]]), np.flatnonzero(full & ~np.r_[full[1:], False]) + 1
    for start, end in zip(starts, ends):
        if runs and t_s[start] - t_s[runs[-1][1]] < MIN_HEATUP_S:
            runs[-1][1] = int(end)
        else:
            runs.append([int(start), int(end)])
    heatups = {s: e for s, e in runs if t_s[min(e, last)] - t_s[s] >= MIN_HEATUP_S}
    bounds = sorted({int(on[0])} | {int(s) for s in heatups if s >= on[0]}) + [len(t_s)]
    segments = []
    for start, stop in itertools.pairwise(bounds):
        settled_s = t_s[min(heatups.get(start, start), last)]
        stop = min(stop, int(np.searchsorted(t_s, settled_s + HOLD_AFTER_S, side="right")))
        if target_c is not None:
            settled = int(np.searchsorted(t_s, settled_s))
            changes = np.flatnonzero(target_c[settled:stop] != target_c[settled])
            stop = settled + int(changes[0]) if changes.size else stop
        if stop - start >= MIN_SAMPLES:
            segments.append(_segment(label, t_s[start:stop], temp_c[start:stop], duty[start:stop], max_power,
                                     between))
    return segments


def _stats_segments(log: StatsLog, heater: str | None, session: int | None) -> tuple[str, list[Segment]]:
    names = sorted({name for s in log.sessions for name in s})
    heater = heater or ("extruder" if "extruder" in names else names[0])
    if heater not in names:
        raise NotFittable(f"no heater {heater!r} in this Klipper log; it has {', '.join(names)}")
    if session is not None and not 0 <= session < len(log.sessions):
        raise NotFittable(f"no session {session}: the log has sessions 0..{len(log.sessions) - 1}")
    max_power = float(log.meta["config"].get(heater, {}).get("max_power", 1.0))
    segments = []
    for index, heaters in enumerate(log.sessions):
        series: HeaterSeries | None = heaters.get(heater)
        if series is None or session not in (None, index):
            continue
        for part in series.segments():
            segments += split_heatups(f"session {index}, ", part.t_s, part.temp_c, part.pwm, max_power,
                                      "closed loop: the pwm Klipper last sent", part.target_c)
    if not segments:
        where = f"session {session}" if session is not None else "any session"
        raise NotFittable(f"{heater} never heats for {MIN_SAMPLES} or more Stats lines in {where}")
    return heater, segments


def _relay_segment(log: M303Log, run: list, heater_key: str) -> Segment:
    """A run of status lines as a Segment, 2 s apart, the relay's switches reconstructed (tools/ident/relay_trace.py)."""
    t_s = M303_STATUS_PERIOD_S * np.arange(len(run))
    temp_c = np.array([s.temp_c for s in run])
    duty = np.array([s.power for s in run]) / log.power_max
    target_c = command_target_c(log, heater_key, run[0].line_no)
    how = "from the M303 command"
    if target_c is None:
        target_c, how = estimate_target_c(temp_c, duty > duty.min()), "estimated from the switches"
    seg = _segment(f"lines {run[0].line_no}..{run[-1].line_no}, ", t_s, temp_c, duty, 1.0, "relay levels",
                   f"; {M303_STATUS_PERIOD_S:g} s per status line, which carry no time")
    if target_c is None:
        return seg
    t_s, temp_c, duty, observed = switch_instants(t_s, temp_c, duty, target_c)
    # Before the first switch the fit's start (every node at one temperature) is wrong mid-cycle: a
    # burn-in, simulated but not compared.
    observed[: int(np.argmin(observed))] = False
    note = f"{seg.note}; relay target {target_c:g} C ({how}), switches put at its crossings, compared from the first"
    return seg._replace(t_s=t_s, temp_c=temp_c, duty=duty, observed=observed, target_c=target_c, note=note)


def _m303_segments(log: M303Log, heater: str | None) -> tuple[str, list[Segment]]:
    """Runs of a heater's 2 s status reports, cut where lines are missing; by default the
    extruder's, else the bed's."""
    keys = {"extruder": "T", "heater_bed": "B"}
    if heater is not None and heater not in keys:
        raise NotFittable(f"Marlin console text has heaters {', '.join(keys)}, not {heater!r}")
    cut_lines = np.array([no for no, _ in log.skipped])
    for name in [heater] if heater else keys:
        runs: list[list] = []
        status = [s for s in log.status if s.heater == keys[name]]
        for s in status:
            prev = runs[-1][-1].line_no if runs else -M303_MAX_LINE_STEP
            if s.line_no - prev > M303_MAX_LINE_STEP or np.any((cut_lines > prev) & (cut_lines < s.line_no)):
                runs.append([])
            runs[-1].append(s)
        segments = [_relay_segment(log, run, keys[name]) for run in runs if len(run) >= M303_MIN_SAMPLES]
        if segments:
            return name, segments
    raise NotFittable(f"Marlin autotune output with {len(log.cycles)} relay cycles and {len(log.status)} status "
                      f"lines{' of the ' + heater if heater else ''}: no run of {M303_MIN_SAMPLES} or more status "
                      "reports (T:/B: and @:) to fit")


def log_segments(log: Log, heater: str | None = None, session: int | None = None) -> tuple[str, list[Segment]]:
    """The heater (default: extruder) and its segments worth fitting, in the log's order.

    Klipper Stats: each gap-free run of a session split at heat-ups (runs at max_power); heattests
    the same (each pulse and its cooling, open loop); Marlin M303 text: runs of 2 s status reports;
    a plain CSV: the whole series. NotFittable says why a log has none.
    """
    if isinstance(log, StatsLog):
        return _stats_segments(log, heater, session)
    if isinstance(log, M303Log):
        return _m303_segments(log, heater)
    if isinstance(log, HeattestLog):
        segments = split_heatups("", log.t_s, log.temp_c, log.pwm)
    elif isinstance(log, PlainLog):
        segments = [_segment("", log.t_s, log.temp_c, log.duty, 1.0, "as logged")]
    else:
        raise NotFittable("Klipper PID_CALIBRATE results: PID gains only, no temperature trace")
    if not segments:
        raise NotFittable("the heater never turns on for long enough in this log")
    return heater or "extruder", segments
