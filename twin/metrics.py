"""Step-response and disturbance metrics: the project's one place where they are defined.

Every tool (tuning, comparison, log replay) computes its numbers here, on simulation traces and
on real logs alike (Klipper's Stats lines come at about 1 Hz, with jitter and gaps), so nothing
assumes a regular sample period.

A step is a segment of a trace with a constant target ``target_c``. Its starting temperature
``start_c`` is the temperature of the segment's first sample, its size is
``D = target_c - start_c`` (negative for a cooling step) and its time origin ``t0`` is the step
start (``start_s``). All times below are measured from ``t0``; ``e(t) = target_c - temp(t)``.

- rise_time_s: from the first time the temperature has covered 10 % of D to the first time it has
  covered 90 % of D, both counted from ``start_c`` in the direction of the step.
- time_to_band_s: first time ``|e| <= band_c`` (2 C by default).
- overshoot_c: ``max(0, max(sign(D) * (temp - target_c)))`` over the samples, the peak beyond the
  target in the direction of the step; overshoot_pct is ``100 * overshoot_c / |D|``;
  peak_time_s is the time of that peak.
- settling_time_2pct_s / _5pct_s: the time after which ``|e| <= 0.02 |D|`` (``0.05 |D|``) holds up
  to the end of the segment.
- steady_state_error_c: the time-weighted mean of ``e`` over the last ``min(steady_window_s,
  10 % of the segment)`` seconds of the segment; None where the hold limit-cycles (no steady state).
- limit_cycle_amplitude_c / limit_cycle_period_s: a sustained periodic oscillation during the hold
  (from time_to_band on), well above the readings' noise and quantisation (``limit_cycle``):
  half its median peak-to-peak and its median period; None where the hold has none.
- iae_c_s = integral of ``|e| dt``; itae_c_s2 = integral of ``(t - t0) |e| dt``;
  duty_sq_s = integral of ``duty^2 dt`` with duty in 0..1 (control effort, as in a quadratic cost).
- recovery_time_s (after a disturbance at ``disturbance_s``): the time after which
  ``|e| <= band_c`` holds up to the end of the trace; max_deviation_c: the largest ``|e|``
  from ``disturbance_s`` on.

A limit cycle (``limit_cycle``, also on a (rows, lanes) batch): the error about its mean over the
hold, ``x``, counted as crossing only when it goes from below ``-h`` to above ``+h`` or back (a
Schmitt trigger), ``h`` the larger of
- LIMIT_CYCLE_NOISE_SIGMAS = 4 standard deviations of the readings' sample-to-sample noise, from the
  median absolute second difference (a smooth oscillation's second difference over one reading is
  nearly 0; white noise's has standard deviation sqrt(6) sigma): a Gaussian reading passes 4 sigma
  on a given side in 3e-5 of its samples, so noise alone makes a crossing about once in 10^4.5
  readings (1.5 h of Marlin's 0.164 s readings), and a cycle needs two in a row;
- LIMIT_CYCLE_READING_STEPS = 2 reading steps, the median non-zero change between two readings: a
  quantised loop that holds dithers over 2 or 3 adjacent readings (peak-to-peak up to 2 steps, a
  half-amplitude of 1); an oscillation of 4 steps peak-to-peak or more is no dither.
It is a limit cycle where the crossings span LIMIT_CYCLE_MIN_CYCLES = 2 full periods or more, the
last crossing is less than one period before the end of the hold (it is still going), and the last
period's peak-to-peak (from its first crossing to the end) lies within LIMIT_CYCLE_SWING_RATIO = 2 of
the median one (sustained: an oscillation that decays is settling, one that grows diverges). The
period is the median time between crossings in the same direction; the amplitude, half the median
peak-to-peak between them. A hold that is noisy but stable never crosses both thresholds in turn.

Conventions:
- Crossing times are linearly interpolated between the two samples around the crossing.
- Temperature integrals use the trapezoid rule (temperature is continuous between samples); the
  duty integral uses a zero-order hold, ``sum(duty[i]^2 (t[i+1] - t[i]))``, because a heater's
  PWM holds each value until the next one; the last sample's duty therefore adds nothing.
- Peaks are sample values (no interpolation). Integrals run from the segment's first sample to
  its last.
- Anything not reached within the segment is None, never NaN or 0. With D = 0 the metrics
  relative to D (rise, overshoot, settling, peak) are None; the absolute ones are still computed.
- Every metric is relative to ``start_c`` and to the target, never to 0 or to the last sample.

The python-control pitfall: ``control.step_info(y, T)`` places the rise thresholds at 10 % and
90 % of the final value, the settling band at 2 % of the final value and the overshoot relative to
the final value, i.e. it assumes the response starts at 0 (and that the final sample is the
target). A bed heating from 25 C to 60 C already sits above "10 %" (6 C) at t = 0: its rise time
comes out 20 % short, its 2 % settling band is 1.2 C instead of 0.7 C and its overshoot percentage
35/60 of the true one. Hence this module.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import astuple, dataclass, fields

import numpy as np

RISE_FROM, RISE_TO = 0.1, 0.9  # 10-90 %, the default of MATLAB stepinfo and python-control step_info
SETTLING_BANDS = (0.02, 0.05)  # fractions of the step size
STEADY_FRACTION = 0.1  # steady window at most this fraction of the segment
# A limit cycle's thresholds (module docstring says why these values)
LIMIT_CYCLE_NOISE_SIGMAS = 4.0  # the crossing threshold in standard deviations of the reading noise
LIMIT_CYCLE_READING_STEPS = 2.0  # ... and at least this many reading steps
LIMIT_CYCLE_MIN_CYCLES = 2  # full periods the crossings must span
LIMIT_CYCLE_SWING_RATIO = 2.0  # the last period's swing within this factor of the median: sustained
MAD_TO_SIGMA = 1.4826  # a Gaussian's standard deviation per median absolute deviation
SECOND_DIFFERENCE_GAIN = math.sqrt(6.0)  # std of x[i+1] - 2 x[i] + x[i-1] for white noise of std 1


@dataclass(frozen=True)
class StepMetrics:
    """Metrics of one step (see the module docstring for the definitions); None = not reached."""

    start_c: float
    target_c: float
    reached: bool
    rise_time_s: float | None
    time_to_band_s: float | None
    overshoot_c: float | None
    overshoot_pct: float | None
    peak_time_s: float | None
    settling_time_2pct_s: float | None
    settling_time_5pct_s: float | None
    steady_state_error_c: float | None  # None: the hold limit-cycles, there is no steady state
    limit_cycle_amplitude_c: float | None
    limit_cycle_period_s: float | None
    iae_c_s: float
    itae_c_s2: float
    duty_sq_s: float | None


def _times(t_s) -> np.ndarray:
    """Validated sample times: 1-D, finite, strictly increasing, at least 2."""
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"t_s must be a 1-D array of at least 2 samples, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("t_s holds NaN or infinite values")
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_s must be strictly increasing")
    return t


def _like(t: np.ndarray, name: str, values, scalar_ok: bool = True) -> np.ndarray:
    """values as a finite float array sampled at t (a scalar is held for the whole trace)."""
    a = np.asarray(values, dtype=float)
    if scalar_ok and a.ndim == 0:
        a = np.full(t.shape, a)
    if a.shape != t.shape:
        raise ValueError(f"{name} must be a 1-D array as long as t_s ({t.size}), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds NaN or infinite values")
    return a


def _trapezoid(t: np.ndarray, y: np.ndarray) -> float:
    """Integral of the samples y(t), trapezoid rule."""
    return float(np.sum(np.diff(t) * (y[1:] + y[:-1]) / 2))


def _cross_time(t: np.ndarray, x: np.ndarray, i: int, j: int, level: float) -> float:
    """Time where the line through samples i and j of x equals level."""
    return float(t[i] + (level - x[i]) / (x[j] - x[i]) * (t[j] - t[i]))


def _first_reach(t: np.ndarray, x: np.ndarray, level: float) -> float | None:
    """First time x >= level, interpolated; None if never."""
    hits = np.flatnonzero(x >= level)
    if hits.size == 0:
        return None
    i = int(hits[0])
    return float(t[0]) if i == 0 else _cross_time(t, x, i - 1, i, level)


def _first_in_band(t: np.ndarray, e: np.ndarray, band: float, origin_s: float) -> float | None:
    """Time from origin_s to the first |e| <= band, interpolated on the edge crossed; None if never."""
    hits = np.flatnonzero(np.abs(e) <= band)
    if hits.size == 0:
        return None
    i = int(hits[0])
    time_s = float(t[0]) if i == 0 else _cross_time(t, e, i - 1, i, math.copysign(band, e[i - 1]))
    return time_s - origin_s


def _settled_after(t: np.ndarray, e: np.ndarray, band: float, origin_s: float) -> float | None:
    """Time from origin_s after which |e| <= band to the end (0 if never out); None if out at the end."""
    out = np.flatnonzero(np.abs(e) > band)
    if out.size == 0:
        return 0.0
    j = int(out[-1])
    if j == e.size - 1:
        return None
    return _cross_time(t, e, j, j + 1, math.copysign(band, e[j])) - origin_s


def _steady_error(t: np.ndarray, e: np.ndarray, window_s: float) -> float:
    """Time-weighted mean of e over the samples of the last window_s (the last sample if alone)."""
    last = t >= t[-1] - window_s
    if np.count_nonzero(last) < 2:
        return float(e[-1])
    return _trapezoid(t[last], e[last]) / float(t[-1] - t[last][0])


@dataclass(frozen=True)
class LimitCycle:
    """A sustained oscillation during a hold (module docstring): half its median peak-to-peak, its median
    period, and how many full periods its crossings span."""

    amplitude_c: float
    period_s: float
    cycles: int


def _nanmedian(a: np.ndarray) -> np.ndarray:
    """The median over axis 0 of the non-NaN values; NaN for a lane with none."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice": a lane that never reached the band
        return np.nanmedian(a, axis=0)


def _crossing_threshold_c(temp: np.ndarray, hold: np.ndarray) -> np.ndarray:
    """Per lane, the Schmitt threshold h (module docstring): LIMIT_CYCLE_NOISE_SIGMAS noise sigmas or
    LIMIT_CYCLE_READING_STEPS reading steps over the hold, the larger; inf where the readings never change."""
    second = np.where(hold[:-2], temp[2:] - 2.0 * temp[1:-1] + temp[:-2], np.nan)
    sigma_c = MAD_TO_SIGMA * _nanmedian(np.abs(second - _nanmedian(second))) / SECOND_DIFFERENCE_GAIN
    change = np.abs(np.diff(temp, axis=0))
    step_c = _nanmedian(np.where(hold[:-1] & (change > 0), change, np.nan))
    h = np.fmax(LIMIT_CYCLE_NOISE_SIGMAS * sigma_c, LIMIT_CYCLE_READING_STEPS * step_c)
    return np.where(np.isfinite(h) & (h > 0), h, np.inf)


def _lane_cycle(t: np.ndarray, x: np.ndarray, passes: np.ndarray) -> LimitCycle | None:
    """One lane's limit cycle from the samples where x passed the opposite threshold, or None."""
    if passes.size < 2 * LIMIT_CYCLE_MIN_CYCLES + 1:
        return None
    period_s = float(np.median(t[passes[2:]] - t[passes[:-2]]))
    swing_c = float(np.median([np.ptp(x[a : b + 1]) for a, b in zip(passes[:-2], passes[2:])]))
    last_swing_c = float(np.ptp(x[passes[-3] :]))
    if t[-1] - t[passes[-1]] > period_s or not 1 / LIMIT_CYCLE_SWING_RATIO <= last_swing_c / swing_c \
            <= LIMIT_CYCLE_SWING_RATIO:
        return None  # it died out, or it grows or decays: not sustained
    return LimitCycle(swing_c / 2.0, period_s, (passes.size - 1) // 2)


def limit_cycles(t_s, temp_c, target_c, *, band_c: float = 2.0) -> list[LimitCycle | None]:
    """The limit cycle of each lane's hold (module docstring), or None where it has none.

    temp_c: (rows, lanes) readings at t_s; target_c a scalar or an array like t_s, constant (one step);
    the hold of a lane starts at its first reading within band_c of the target."""
    t = _times(t_s)
    temp = np.asarray(temp_c, dtype=float)
    if temp.ndim != 2 or temp.shape[0] != t.size:
        raise ValueError(f"temp_c must be (rows, lanes) with {t.size} rows, got shape {temp.shape}")
    if not np.all(np.isfinite(temp)):
        raise ValueError("temp_c holds NaN or infinite values")
    target = _like(t, "target_c", target_c)
    if np.any(target != target[0]):
        raise ValueError("target_c changes: a limit cycle is sought in one step's hold (split with segments())")
    error = target[0] - temp
    inside = np.abs(error) <= band_c
    rows = np.arange(t.size)[:, None]
    hold = (rows >= np.argmax(inside, axis=0)) & inside.any(axis=0)
    centre = np.sum(np.where(hold, error, 0.0), axis=0) / np.maximum(np.count_nonzero(hold, axis=0), 1)
    x = error - centre
    h = _crossing_threshold_c(temp, hold)
    side = np.where(hold & (x >= h), 1, np.where(hold & (x <= -h), -1, 0))
    last = np.maximum.accumulate(np.where(side != 0, rows, 0), axis=0)  # the last sample past a threshold
    state = np.take_along_axis(side, last, axis=0)  # the side last passed, 0 before any
    passed = (state[1:] != state[:-1]) & (state[:-1] != 0)
    return [_lane_cycle(t, x[:, k], np.flatnonzero(passed[:, k]) + 1) for k in range(temp.shape[1])]


def limit_cycle(t_s, temp_c, target_c, *, band_c: float = 2.0) -> LimitCycle | None:
    """The limit cycle of one trace's hold (``limit_cycles`` on one lane), or None."""
    t = _times(t_s)
    return limit_cycles(t, _like(t, "temp_c", temp_c, scalar_ok=False)[:, None], target_c, band_c=band_c)[0]


def step_metrics(
    t_s,
    temp_c,
    target_c,
    duty=None,
    *,
    start_s: float | None = None,
    end_s: float | None = None,
    band_c: float = 2.0,
    steady_window_s: float = 30.0,
) -> StepMetrics:
    """Metrics of the step made by the samples with start_s <= t < end_s (default: the whole trace).

    target_c and duty (0..1) are scalars or arrays like t_s; the target must not change inside
    the segment (split the trace with segments()). Heating, cooling and zero-size steps all work.
    """
    t = _times(t_s)
    temp = _like(t, "temp_c", temp_c, scalar_ok=False)
    target = _like(t, "target_c", target_c)
    if duty is not None:
        duty = _like(t, "duty", duty)
        if np.any((duty < 0) | (duty > 1)):
            raise ValueError("duty must be within 0..1")
    if band_c <= 0 or steady_window_s <= 0:
        raise ValueError("band_c and steady_window_s must be positive")

    t0 = float(t[0]) if start_s is None else float(start_s)
    end = math.inf if end_s is None else float(end_s)
    inside = (t >= t0) & (t < end)
    if np.count_nonzero(inside) < 2:
        raise ValueError(f"the segment [{t0}, {end}) s holds fewer than 2 samples")
    t, temp, target = t[inside], temp[inside], target[inside]
    duty = None if duty is None else duty[inside]
    changed = np.flatnonzero(target != target[0])
    if changed.size:
        raise ValueError(
            f"target_c changes inside the segment (at t = {t[changed[0]]} s); "
            "split the trace with segments()"
        )

    start, goal = float(temp[0]), float(target[0])
    step_c = goal - start
    e = goal - temp
    time_to_band = _first_in_band(t, e, band_c, t0)
    steady_window_s = min(steady_window_s, STEADY_FRACTION * float(t[-1] - t[0]))
    rise = overshoot = overshoot_pct = peak_time = None
    settling: list[float | None] = [None] * len(SETTLING_BANDS)
    if step_c != 0:
        size_c = abs(step_c)
        progress_c = math.copysign(1.0, step_c) * (temp - start)
        reach_to = _first_reach(t, progress_c, RISE_TO * size_c)
        reach_from = _first_reach(t, progress_c, RISE_FROM * size_c)
        if reach_to is not None and reach_from is not None:  # reaching 90 % implies reaching 10 %
            rise = reach_to - reach_from
        beyond_c = progress_c - size_c
        i_peak = int(np.argmax(beyond_c))
        overshoot = max(0.0, float(beyond_c[i_peak]))
        overshoot_pct = 100.0 * overshoot / size_c
        peak_time = float(t[i_peak]) - t0 if overshoot > 0 else None
        settling = [_settled_after(t, e, fraction * size_c, t0) for fraction in SETTLING_BANDS]

    cycle = limit_cycle(t, temp, goal, band_c=band_c)
    return StepMetrics(
        start_c=start,
        target_c=goal,
        reached=time_to_band is not None,
        rise_time_s=rise,
        time_to_band_s=time_to_band,
        overshoot_c=overshoot,
        overshoot_pct=overshoot_pct,
        peak_time_s=peak_time,
        settling_time_2pct_s=settling[0],
        settling_time_5pct_s=settling[1],
        steady_state_error_c=_steady_error(t, e, steady_window_s) if cycle is None else None,
        limit_cycle_amplitude_c=None if cycle is None else cycle.amplitude_c,
        limit_cycle_period_s=None if cycle is None else cycle.period_s,
        iae_c_s=_trapezoid(t, np.abs(e)),
        itae_c_s2=_trapezoid(t, (t - t0) * np.abs(e)),
        duty_sq_s=None if duty is None else float(np.sum(np.diff(t) * duty[:-1] ** 2)),
    )


def _errors_after(t_s, temp_c, target_c, disturbance_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Times and errors (target - temp) of the samples at or after disturbance_s."""
    t = _times(t_s)
    e = _like(t, "target_c", target_c) - _like(t, "temp_c", temp_c, scalar_ok=False)
    after = t >= disturbance_s
    if not np.any(after):
        raise ValueError(f"no samples at or after disturbance_s = {disturbance_s} s")
    return t[after], e[after]


def recovery_time_s(t_s, temp_c, target_c, disturbance_s: float, band_c: float = 2.0) -> float | None:
    """Time from disturbance_s until |target - temp| <= band_c for good (0 if never out), or None."""
    t, e = _errors_after(t_s, temp_c, target_c, disturbance_s)
    return _settled_after(t, e, band_c, disturbance_s)


def max_deviation_c(t_s, temp_c, target_c, disturbance_s: float) -> float:
    """Largest |target - temp| from disturbance_s on."""
    _, e = _errors_after(t_s, temp_c, target_c, disturbance_s)
    return float(np.max(np.abs(e)))


def segments(t_s, target_c) -> list[tuple[float, float]]:
    """Constant-target segments [start_s, end_s): each ends where the next starts, the last at inf."""
    t = _times(t_s)
    target = _like(t, "target_c", target_c, scalar_ok=False)
    starts = [float(t[0])] + [float(t[i]) for i in np.flatnonzero(np.diff(target)) + 1]
    return list(zip(starts, starts[1:] + [math.inf]))


def _cell(value: float | bool | None) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:z.2f}"  # z: no "-0.00"


def format_metrics_table(metrics: StepMetrics | Sequence[StepMetrics]) -> str:
    """Plain-text table: one row per metric (units in the names), one column per step; None is "-"."""
    steps = [metrics] if isinstance(metrics, StepMetrics) else list(metrics)
    names = [f.name for f in fields(StepMetrics)]
    header = ["metric"] + [f"step {k + 1}" for k in range(len(steps))]
    columns = [astuple(step) for step in steps]
    rows = [header] + [[name] + [_cell(v) for v in values] for name, *values in zip(names, *columns)]
    widths = [max(len(row[k]) for row in rows) for k in range(len(header))]
    return "\n".join(
        "  ".join([row[0].ljust(widths[0])] + [cell.rjust(w) for cell, w in zip(row[1:], widths[1:])])
        for row in rows
    )
