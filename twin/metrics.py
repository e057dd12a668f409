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
  10 % of the segment)`` seconds of the segment.
- iae_c_s = integral of ``|e| dt``; itae_c_s2 = integral of ``(t - t0) |e| dt``;
  duty_sq_s = integral of ``duty^2 dt`` with duty in 0..1 (control effort, as in a quadratic cost).
- recovery_time_s (after a disturbance at ``disturbance_s``): the time after which
  ``|e| <= band_c`` holds up to the end of the trace; max_deviation_c: the largest ``|e|``
  from ``disturbance_s`` on.

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
from collections.abc import Sequence
from dataclasses import astuple, dataclass, fields

import numpy as np

RISE_FROM, RISE_TO = 0.1, 0.9  # 10-90 %, the default of MATLAB stepinfo and python-control step_info
SETTLING_BANDS = (0.02, 0.05)  # fractions of the step size
STEADY_FRACTION = 0.1  # steady window at most this fraction of the segment


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
    steady_state_error_c: float
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
        steady_state_error_c=_steady_error(t, e, steady_window_s),
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
