"""First order plus dead time: the two-point method on a step response (seed 001), the ultimate
point of a FOPDT, a FOPDT back from a relay result, and the FOPDT equivalent of a fitted model.

Tuning: a fitted model's FOPDT equivalent plus the control loop's own delay gives PID gains by the
AMIGO rule (tools/tuning/rules.py), and its ultimate point (Ku, Tu), what an ideal relay autotune
would find; relay_fopdt turns a logged relay result back into a FOPDT.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tools.ident.response import radiating_response, spec_lti
from tools.ident.result import FitResult
from twin.linear import SENSOR, TICK_S, TickModel
from twin.plants import Plant

# Smith's two-point method (seed 001 eq. (8), which attributes it to Cohen-Coon): T = 1.5 (t2 - t1),
# delay = t2 - T, with t1, t2 the times to these fractions of the step's rise. Exact for a FOPDT;
# the seed rounds the first fraction to 0.28.
TWO_POINT_FRACTIONS = (1.0 - math.exp(-1.0 / 3.0), 1.0 - math.exp(-1.0))


# Tuning: the PID loop's own delay on top of the plant's. Klipper applies a pwm 0.3 s after the
# sample it answers (pwm_delay) and samples every 0.3 s (half a period on average); Marlin's
# 0.164 s control period is shorter, so this errs on the safe side for it.
CONTROL_DELAY_S = 0.3 + 0.3 / 2
STEP_RESPONSE_POINTS = 20000  # the grid of a model's step response for its FOPDT equivalent
RADIATING_STEP_POINTS = 2000  # a radiating model's: a matrix exponential per point (0.4 % of a time constant each)


class Fopdt(NamedTuple):
    """First order plus dead time: gain_c (C of rise per unit of input) e^(-delay_s s) / (time_constant_s s + 1)."""

    gain_c: float
    time_constant_s: float
    delay_s: float


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
    import scipy.optimize  # here: a command's start-up needs no scipy
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
        return Fopdt(*(result.values[name] for name in Fopdt._fields))
    spec = result.spec()
    ambient_c = result.values.get("ambient_c", 0.0)
    lti = spec_lti(spec, ambient_c)
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


