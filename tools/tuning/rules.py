"""Tuning rules as pure functions: a model in, ``Gains`` out, each with its formula's source.

FOPDT rules take a ``Fopdt`` (tools/ident/fit.py: gain_c in degC per unit heater duty, the time
constant, the dead time); ultimate-cycle rules an ``UltimatePoint`` (tools/tuning/ultimate.py: Ku
in duty per degC, Tu). Standard-form settings Kp (1 + 1/(Ti s) + Td s) become parallel gains on the
0..255 scale of Marlin's M301 and Klipper's pid_K* (tools/tuning/gains.py). ``RULES`` lists every
rule by name, with what it needs, a one-line description and its source, for a CLI:

    gains = tune("simc", model_of(SPECS["seed001_fopdt"]).delayed(0.3))
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from firmware_port.klipper.pid_calibrate import zn_from_relay
from firmware_port.marlin.autotune import pid_from_relay
from tools.ident.fopdt import Fopdt
from tools.tuning.gains import COUNTS_PER_DUTY, Gains
from tools.tuning.models import LinearModel
from tools.tuning.msdi import msdi_gains
from tools.tuning.ultimate import UltimatePoint, ultimate_point


def _standard(kp_duty: float, ti_s: float, td_s: float) -> Gains:
    return Gains.from_ti_td(kp_duty * COUNTS_PER_DUTY, ti_s, td_s)


def _check_fopdt(fopdt: Fopdt) -> tuple[float, float, float]:
    k, tau, delay = fopdt
    if not (k > 0 and tau > 0 and delay > 0):
        raise ValueError(f"{fopdt}: the rule needs a positive gain, time constant and dead time")
    return k, tau, delay


def _check_point(point: UltimatePoint) -> tuple[float, float]:
    if not (point.ku > 0 and point.tu_s > 0 and math.isfinite(point.ku)):
        raise ValueError(f"{point}: the rule needs a finite positive Ku and Tu")
    return point.ku, point.tu_s


def ziegler_nichols_step(fopdt: Fopdt) -> Gains:
    """Ziegler and Nichols 1942 ("Optimum settings for automatic controllers", Trans. ASME 64:759-768),
    reaction-curve method: with a = K L / T, Kp = 1.2 / a, Ti = 2 L, Td = L / 2."""
    k, tau, delay = _check_fopdt(fopdt)
    return _standard(1.2 * tau / (k * delay), 2.0 * delay, 0.5 * delay)


def ziegler_nichols_ultimate(point: UltimatePoint) -> Gains:
    """Ziegler and Nichols 1942, ultimate-cycle method: Kp = 0.6 Ku, Ti = Tu / 2, Td = Tu / 8."""
    ku, tu = _check_point(point)
    return _standard(0.6 * ku, 0.5 * tu, 0.125 * tu)


def tyreus_luyben(point: UltimatePoint) -> Gains:
    """Tyreus and Luyben 1992 ("Tuning PI controllers for integrator/dead time processes", Ind. Eng.
    Chem. Res. 31:2625-2628), PID settings as in Luyben and Luyben, Essentials of Process Control
    (1997): Kp = Ku / 2.2, Ti = 2.2 Tu, Td = Tu / 6.3."""
    ku, tu = _check_point(point)
    return _standard(ku / 2.2, 2.2 * tu, tu / 6.3)


def cohen_coon(fopdt: Fopdt) -> Gains:
    """Cohen and Coon 1953 ("Theoretical consideration of retarded control", Trans. ASME 75:827-834),
    PID: with r = L / T, Kp = (T / (K L)) (4/3 + r/4), Ti = L (32 + 6 r) / (13 + 8 r),
    Td = 4 L / (11 + 2 r)."""
    k, tau, delay = _check_fopdt(fopdt)
    r = delay / tau
    return _standard(tau / (k * delay) * (4.0 / 3.0 + r / 4.0), delay * (32.0 + 6.0 * r) / (13.0 + 8.0 * r),
                     4.0 * delay / (11.0 + 2.0 * r))


def amigo(fopdt: Fopdt) -> Gains:
    """AMIGO step-response rule, Astrom and Hagglund 2004 ("Revisiting the Ziegler-Nichols step
    response method for PID control", J. Process Control 14:635-650), eq. (10):
    Kp = (0.2 + 0.45 T / L) / K, Ti = L (0.4 L + 0.8 T) / (L + 0.1 T), Td = 0.5 L T / (0.3 L + T).
    For a loop with its own delay (Marlin's control period), add that delay to the FOPDT first."""
    k, tau, delay = _check_fopdt(fopdt)
    return _standard((0.2 + 0.45 * tau / delay) / k, delay * (0.4 * delay + 0.8 * tau) / (delay + 0.1 * tau),
                     0.5 * delay * tau / (0.3 * delay + tau))


def simc(fopdt: Fopdt, tau_c_s: float | None = None) -> Gains:
    """SIMC PI rule for a FOPDT, Skogestad 2003 ("Simple analytic rules for model reduction and PID
    controller tuning", J. Process Control 13:291-309), eqs. (21)-(22): Kp = T / (K (tau_c + L)),
    Ti = min(T, 4 (tau_c + L)), no derivative; tau_c the desired closed-loop time constant, the
    paper's default tau_c = L (tight control with good robustness)."""
    k, tau, delay = _check_fopdt(fopdt)
    tau_c = delay if tau_c_s is None else tau_c_s
    if tau_c < 0:
        raise ValueError(f"tau_c_s={tau_c_s!r}: must be >= 0")
    return _standard(tau / (k * (tau_c + delay)), min(tau, 4.0 * (tau_c + delay)), 0.0)


def marlin_classic(point: UltimatePoint) -> Gains:
    """What Marlin's M303 computes from this ultimate point ("Classic PID": Kp = 0.6 Ku, Ki = 2 Kp / Tu,
    Kd = Kp Tu / 8 in float32; Marlin 2.1.x Marlin/src/module/temperature.cpp PID_autotune), with Ku on
    the 0..255 scale as M303 prints it and Tu in whole milliseconds, through firmware_port.marlin.autotune."""
    ku, tu = _check_point(point)
    _, kp, ki, kd = pid_from_relay(np.float32(ku * COUNTS_PER_DUTY), round(tu * 1000), no_overshoot=False)
    return Gains(float(kp), float(ki), float(kd))


def marlin_no_overshoot(point: UltimatePoint) -> Gains:
    """Marlin 2.x M303's "No overshoot" variant (used for beds): Kp = 0.2 Ku, Ki = 2 Kp / Tu,
    Kd = Kp Tu / 3 (same source as ``marlin_classic``)."""
    ku, tu = _check_point(point)
    _, kp, ki, kd = pid_from_relay(np.float32(ku * COUNTS_PER_DUTY), round(tu * 1000), no_overshoot=True)
    return Gains(float(kp), float(ki), float(kd))


def klipper(point: UltimatePoint) -> Gains:
    """What Klipper's PID_CALIBRATE computes for this ultimate point (klippy/extras/pid_calibrate.py,
    Ziegler-Nichols with Ti = Tu / 2, Td = Tu / 8, through firmware_port.klipper.pid_calibrate). Its
    relay swings 0..max_power and it takes that full swing for d, so the Ku it measures is twice the
    textbook 4 d / (pi a): Kp = 0.6 (2 Ku) = 1.2 Ku (0..1 duty scale, times 255)."""
    ku, tu = _check_point(point)
    return Gains(*zn_from_relay(2.0 * ku, tu))


class Rule(NamedTuple):
    """A registry entry: ``needs`` says what the function takes ("fopdt", "ultimate" or "model")."""

    function: Callable[..., Gains]
    needs: str
    description: str
    source: str


RULES: dict[str, Rule] = {
    "zn_step": Rule(ziegler_nichols_step, "fopdt", "Ziegler-Nichols reaction curve: Kp 1.2 T/(K L), Ti 2 L, Td L/2",
                    "Ziegler and Nichols 1942, Trans. ASME 64:759-768"),
    "zn_ultimate": Rule(ziegler_nichols_ultimate, "ultimate", "Ziegler-Nichols ultimate cycle: 0.6 Ku, Tu/2, Tu/8",
                        "Ziegler and Nichols 1942, Trans. ASME 64:759-768"),
    "tyreus_luyben": Rule(tyreus_luyben, "ultimate", "Tyreus-Luyben: Ku/2.2, 2.2 Tu, Tu/6.3 (less aggressive ZN)",
                          "Tyreus and Luyben 1992, Ind. Eng. Chem. Res. 31:2625-2628"),
    "cohen_coon": Rule(cohen_coon, "fopdt", "Cohen-Coon PID for a FOPDT (quarter decay)",
                       "Cohen and Coon 1953, Trans. ASME 75:827-834"),
    "amigo": Rule(amigo, "fopdt", "AMIGO step-response PID (robust, Ms about 1.4)",
                  "Astrom and Hagglund 2004, J. Process Control 14:635-650"),
    "simc": Rule(simc, "fopdt", "SIMC PI, tau_c = dead time by default",
                 "Skogestad 2003, J. Process Control 13:291-309"),
    "marlin": Rule(marlin_classic, "ultimate", "Marlin M303 'Classic PID' on this ultimate point",
                   "Marlin 2.1.x Marlin/src/module/temperature.cpp PID_autotune"),
    "marlin_no_overshoot": Rule(marlin_no_overshoot, "ultimate", "Marlin M303 'No overshoot' on this ultimate point",
                                "Marlin 2.1.x Marlin/src/module/temperature.cpp PID_autotune"),
    "klipper": Rule(klipper, "ultimate", "Klipper PID_CALIBRATE's Ziegler-Nichols on this ultimate point",
                    "Klipper klippy/extras/pid_calibrate.py"),
    "msdi": Rule(msdi_gains, "model", "maximal stability degree: triple root at -J, J at the gains' first maximum",
                 "seed 003 (MSDI PID tuning for third-order models with a zero and delay), eqs. (4)-(8)"),
}


def tune(name: str, model: LinearModel, **options: float) -> Gains:
    """The named rule's gains for a model (its FOPDT equivalent or ultimate point as the rule needs);
    options go to the rule (e.g. tau_c_s for simc). ValueError names an unknown rule."""
    if name not in RULES:
        raise ValueError(f"unknown rule {name!r}; valid: {', '.join(RULES)}")
    rule = RULES[name]
    argument: object = {"fopdt": model.fopdt, "ultimate": lambda: ultimate_point(model),
                        "model": lambda: model}[rule.needs]()
    return rule.function(argument, **options)
