"""Refit a structure so that its relay runs at the period the printer's PID_CALIBRATE saw.

A klippy.log's 1 Hz Stats trace carries the last *sent* pwm and cannot show the sub-second lags that set
a hotend's relay period (docs/validation.md section 3); its saved PID_CALIBRATE gains state that period
(tools/tuning/calibration.py). As the M303 fits use the printed cycles (tools/ident/relay_points.py), the
structure's lag that sets the period (REFIT_LAG) is held at the value where the port's PID_CALIBRATE on the
plant, at the middle of the band docs/validation.md uses, relays at the saved Tu, and the rest refitted to
the trace: the best trace fit among those the relay allows. The value is found by doubling (or halving)
the held lag from the fitted one until the period crosses the saved one (at most MAX_DOUBLINGS times),
then bisecting geometrically BISECTIONS times. The refit is then judged as any plant is: it must replay
the log and pass the check against the calibration at the band's ends.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from tools.ident.log_fit import LogFit, LogFitOptions, fit_log
from tools.ident.segments import NotFittable
from tools.logs import Log
from tools.tuning.calibration import SavedCalibration
from tools.tuning.relay_evidence import twin_calibration
from tools.validation import compare

# The lag of each structure that sets the relay's period; +1: a larger value lengthens the period.
REFIT_LAG = {"two_node": ("sensor_responsiveness_per_s", -1), "three_node": ("sensor_responsiveness_per_s", -1),
             "fopdt": ("delay_s", 1), "sopdt": ("delay_s", 1)}
MAX_DOUBLINGS = 7  # a factor of 128 either way
BISECTIONS = 5  # the bracket's ratio 2 shrinks to 2^(1/32): Tu within about 2 %
MIN_DELAY_S = 0.1  # a fitted dead time of zero is doubled from here


def _band_middle_c(heater: str) -> float:
    low, high = compare.CALIBRATION_BAND_C[heater]
    return 0.5 * (low + high)


def refit(log: Log, options: LogFitOptions, fitted: LogFit, info: compare.HeaterInfo,
          saved: SavedCalibration) -> tuple[str, LogFit] | str:
    """(label, the refit) of ``fitted``'s structure; or why there is none, in a phrase."""
    model = fitted.result.model
    if model not in REFIT_LAG:
        return f"{model}: no lag to refit"
    name, sign = REFIT_LAG[model]
    heater, target_c = fitted.heater, _band_middle_c(fitted.heater)

    def at(value: float) -> tuple[float, LogFit | None]:
        """log(the period at ``value`` / the saved one) and the fit; NaN where it does not fit or relay."""
        try:
            fit = fit_log(log, dataclasses.replace(options, model=model, loss=fitted.result.loss,
                                                   fixed=options.fixed + ((name, value),)))
        except (NotFittable, ValueError):
            return math.nan, None
        tu_s, _ = twin_calibration(fit.result, info, heater, target_c)
        return math.log(tu_s / saved.tu_s), fit

    start = max(fitted.result.values.get(name, MIN_DELAY_S), MIN_DELAY_S if name == "delay_s" else 0.0)
    found = _bracket(at, start, sign)
    if isinstance(found, str):
        return f"{model}: {found}"
    (a, gap_a), b, fit = found
    for _ in range(BISECTIONS):
        middle = math.sqrt(a * b)
        gap, trial = at(middle)
        if not math.isfinite(gap) or trial is None:
            break
        fit = trial
        if (gap < 0) == (gap_a < 0):
            a, gap_a = middle, gap
        else:
            b = middle
    held = fit.result.fixed.get(name, math.nan)
    return f"{model}: {name} {held:.4g} (refit: relays at your PID_CALIBRATE's {saved.tu_s:.3g} s)", fit


def _bracket(at: Callable[[float], tuple[float, LogFit | None]], start: float, sign: int
             ) -> tuple[tuple[float, float], float, LogFit] | str:
    """Two values of the lag whose periods straddle the saved one: (the first, its gap), the second and its
    fit; or why there are none."""
    gap, _ = at(start)
    if not math.isfinite(gap):
        return "the fit itself does not relay"
    step = 2.0 ** (sign if gap < 0 else -sign)  # towards the saved period
    value = start
    for _ in range(MAX_DOUBLINGS):
        nxt = value * step
        new_gap, fit = at(nxt)
        if fit is None or not math.isfinite(new_gap):
            return f"no fit relays between {value:.4g} and {nxt:.4g}"
        if (new_gap < 0) != (gap < 0):
            return (value, gap), nxt, fit
        value, gap = nxt, new_gap
    return f"no value within a factor {2 ** MAX_DOUBLINGS} of the fitted one relays at the saved period"


__all__ = ["REFIT_LAG", "refit"]
