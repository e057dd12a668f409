"""Identification from relay results: each cycle a relay autotune prints is a measured point of the
loop, and a model is fitted to those points (with a status trace, to both).

What a cycle tells (Marlin's M303, Marlin/src/module/temperature.cpp PID_autotune): the relay ran
between the levels of the bias line before it, (bias +- d) >> 1 on 0..127; the cycle printed
its period Tu and the lowest and highest reading; and Marlin's bias update at the next switch-on,
bias += d (t_high - t_low) / Tu (integer division), brackets t_high - t_low. The describing
function of the relay makes this the plant's gain and phase at the cycle's frequency, and the
bias that balances the two half-cycles is the duty that holds the target: the static loss. Here
the model's own relay cycle at those levels (tools/ident/relay_loop.py, the 5 s minimum
half-cycle included) is compared with the printed one, so a cycle on Marlin's 10 s floor, whose
Tu says little, still counts through its swing and its extremes.

Klipper's PID_CALIBRATE prints only its gains: Tu = 2 Kp / Ki and the swing
8 max_power 153 / (pi Kp) of one cycle (tools/logs/results.py ``PidCalibrateResult``), the relay
at max_power and 0, switching at the target and 5 C under it. Two numbers: a model with a static
gain, two lags or a lag and a dead time is fitted with the gain held (PLAUSIBLE: not identified).

The printed numbers are compared within their cycle-to-cycle scatter (CYCLE_SCATTER_TU_REL,
CYCLE_SCATTER_SWING_REL): each residual is divided by it, and the standard errors take it as
known (tools/ident/lsq.py ``known_sigma``), or the residuals' own scatter where that is larger.

    points = marlin_points(log, "extruder")
    result = fit_points("fopdt", points, ambient_c=25.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from firmware_port.marlin.constants import BED_MAXTEMP_C, BED_OVERSHOOT_C, MAX_BED_POWER, PID_MAX
from tools.ident.fit import (
    FITTED,
    HELD,
    LUMPED_MODELS,
    MAX_SENSOR_RESPONSIVENESS_PER_S,
    RADIATING_BOUNDS_M2,
    RADIATING_EMISSIVITY,
    RADIATING_PARAM,
    RADIATING_START_M2,
    start_values,
)
from tools.ident.fopdt import Fopdt, relay_fopdt
from tools.ident.lsq import least_squares_fit
from tools.ident.relay_loop import NoOscillation, Relay, RelayCycle, marlin_levels, relay_cycle
from tools.ident.relay_trace import relay_target_c
from tools.ident.response import model_response, model_spec
from tools.ident.result import FitResult
from tools.ident.segments import NotFittable, Segment
from tools.logs import UNKNOWN_HEATER, M303Cycle, M303Log, PidCalibrateResult

# The cycle-to-cycle scatter of a relay's printed cycles: the Artillery bed's six printed cycles
# (hardware_logs m303_bed_artillery_genius_pro_S60_configs641.txt: Tu 32.64..36.48 s, standard
# deviation 3.9 % of the mean; swing 0.39..0.55 C, 12.8 %), the longest run of cycles at one level
# in the captures (tests/tools/ident/test_relay_points.py recomputes it).
CYCLE_SCATTER_TU_REL = 0.04
CYCLE_SCATTER_SWING_REL = 0.13
BIAS_MARGIN = 20  # Marlin: LIMIT(bias, 20, max_pow - 20); a clamped update brackets nothing
HEATER_KEYS = {"extruder": "T", "heater_bed": "B"}
MISSING_PENALTY = 1e3  # a residual (in standard deviations) for a cycle the model cannot oscillate at
BED_MAX_TARGET_C = BED_MAXTEMP_C - BED_OVERSHOOT_C  # Marlin's M303 refuses a bed target above this
UNSAID_HEATER = "no line says which heater: the extruder, as M303 without E tunes"


@dataclass(frozen=True)
class RelayPoint:
    """One printed relay cycle: the relay it ran under and what it printed."""

    line_no: int
    relay: Relay
    tu_s: float
    swing_c: float
    min_c: float | None = None  # Marlin prints both extremes; Klipper's gains give the swing only
    max_c: float | None = None
    asymmetry_s: tuple[float, float] | None = None  # t_high - t_low lies in this interval (Marlin's bias update)
    levels_note: str = ""  # where the levels come from when the capture does not show them

    def residuals(self, cycle: RelayCycle) -> np.ndarray:
        """(model - printed) / scatter for Tu, the extremes (or the swing) and t_high - t_low."""
        sigma_tu_s = CYCLE_SCATTER_TU_REL * self.tu_s
        sigma_c = CYCLE_SCATTER_SWING_REL * self.swing_c
        out = [(cycle.tu_s - self.tu_s) / sigma_tu_s]
        if self.min_c is not None and self.max_c is not None:
            out += [(cycle.min_c - self.min_c) / (sigma_c / math.sqrt(2.0)),
                    (cycle.max_c - self.max_c) / (sigma_c / math.sqrt(2.0))]
        else:
            out.append((cycle.swing_c - self.swing_c) / sigma_c)
        if self.asymmetry_s is not None:
            low, high = self.asymmetry_s
            a = cycle.t_high_s - cycle.t_low_s
            out.append((min(a - low, 0.0) + max(a - high, 0.0)) / sigma_tu_s)  # zero inside the bracket
        return np.array(out)


def _asymmetry_s(before: M303Cycle, after: M303Cycle, tu_s: float, max_pow: int) -> tuple[float, float] | None:
    """t_high - t_low from Marlin's update bias_after = bias_before + d (t_high - t_low) / Tu,
    truncated toward zero; None where the new bias sits on a limit (the update was clamped)."""
    assert before.bias is not None and before.d is not None and after.bias is not None
    if after.bias in (BIAS_MARGIN, max_pow - BIAS_MARGIN) or not before.d:
        return None
    step = after.bias - before.bias
    low, high = (step, step + 1) if step > 0 else (step - 1, step) if step < 0 else (-1, 1)
    return low * tu_s / before.d, high * tu_s / before.d


def heater_evidence(log: M303Log, heater: str) -> str:
    """How a capture's lines say it tunes this heater (the first run of it, tools/logs/m303.py), else ""."""
    return next((run.evidence for run in log.runs if run.heater == HEATER_KEYS[heater]), "")


def relay_heater(log: M303Log) -> tuple[str, str]:
    """The heater whose cycles a capture prints, and how that is known: the bed where every cycle its lines
    attribute is the bed's, the extruder where some are the hotend's; where no line attributes one, the
    relay's target: M303 refuses a bed target above BED_MAX_TARGET_C, and a hotend is tuned at its printing
    temperature, above it."""
    said = {c.heater for c in log.cycles} - {UNKNOWN_HEATER}
    if said:
        heater = "heater_bed" if said == {"B"} else "extruder"
        return heater, heater_evidence(log, heater)
    found = relay_target_c(log, "T", log.cycles[0].line_no) if log.cycles else None
    if found is None:
        return "extruder", UNSAID_HEATER
    target_c = found[0]
    heater = "extruder" if target_c > BED_MAX_TARGET_C else "heater_bed"
    return heater, (f"no line says which heater; the relay's target, {target_c:g} C, is "
                    f"{'above' if heater == 'extruder' else 'within'} Marlin's highest bed target "
                    f"{BED_MAX_TARGET_C:g} C (BED_MAXTEMP - BED_OVERSHOOT)")


def cycles_target_c(log: M303Log, key: str) -> float:
    """The relay's target of a heater's ("T" or "B") printed cycles (relay_target_c, the run of the first);
    NotFittable where none has min and max."""
    cycles = log.cycles_of(key)
    if not cycles or (found := relay_target_c(log, key, cycles[0].line_no)) is None:
        raise NotFittable("no printed cycle with min and max to place the relay's target")
    return found[0]


def marlin_points(log: M303Log, heater: str, target_c: float | None = None) -> list[RelayPoint]:
    """The printed cycles of a heater's M303 run that have Tu, min and max, each with the levels of
    the bias line before it (the cycle ran at those), or its own when the capture starts with it."""
    key = HEATER_KEYS[heater]
    max_pow = MAX_BED_POWER if heater == "heater_bed" else PID_MAX
    cycles = [c for c in log.cycles_of(key) if c.bias is not None]
    if target_c is None:
        target_c = cycles_target_c(log, key)
    points = []
    for i, c in enumerate(cycles):
        if not (c.tu_s and c.min_c is not None and c.max_c is not None and c.max_c > c.min_c):
            continue
        before = cycles[i - 1] if i else None
        levels = before or c
        assert levels.bias is not None and levels.d is not None
        on, off = marlin_levels(levels.bias, levels.d)
        note = "" if before else ("levels assumed from its own bias line (the one before is not in the capture; "
                                  "the bias moves by d (t_high - t_low) / Tu a cycle)")
        asym = _asymmetry_s(before, c, c.tu_s, max_pow) if before else None
        points.append(RelayPoint(c.line_no, Relay.marlin(target_c, on, off), c.tu_s, c.max_c - c.min_c, c.min_c,
                                 c.max_c, asym, note))
    return points


def klipper_points(results: Sequence[PidCalibrateResult], target_c: float) -> list[RelayPoint]:
    """PID_CALIBRATE results as relay points: Tu and the swing their gains imply, at target_c (no
    result here states it)."""
    return [RelayPoint(r.line_no, Relay.klipper(target_c, r.max_power), r.tu_s, r.peak_to_peak_c) for r in results]


def point_residuals(spec, ambient_c: float, points: Sequence[RelayPoint]) -> np.ndarray:
    """The points' residuals for one plant; a cycle it cannot oscillate at costs MISSING_PENALTY each."""
    out: list[np.ndarray] = []
    cache: dict[Relay, RelayCycle | None] = {}
    for p in points:
        if p.relay not in cache:
            try:
                cache[p.relay] = relay_cycle(spec, ambient_c, p.relay)
            except NoOscillation:
                cache[p.relay] = None
        cycle = cache[p.relay]
        n = 2 + (p.min_c is not None) + (p.asymmetry_s is not None)
        out.append(np.full(n, MISSING_PENALTY) if cycle is None else p.residuals(cycle))
    return np.concatenate(out)


def fopdt_guess(points: Sequence[RelayPoint], ambient_c: float) -> Fopdt:
    """Start values from the first point: the static gain from the duty that holds the middle of
    its swing, the lags through its describing-function Ku and Tu (``relay_fopdt``)."""
    p = points[0]
    r = p.relay
    asym = 0.0 if p.asymmetry_s is None else sum(p.asymmetry_s) / 2.0
    t_high = (p.tu_s + asym) / 2.0
    mean_duty = (r.on_duty * t_high + r.off_duty * (p.tu_s - t_high)) / p.tu_s
    middle_c = (p.min_c + p.max_c) / 2.0 if p.min_c is not None and p.max_c is not None else r.target_c
    gain_c = max(middle_c - ambient_c, 1.0) / max(mean_duty, 1e-3)
    ku = 4.0 * (r.on_duty - r.off_duty) / 2.0 / (math.pi * p.swing_c / 2.0)
    try:
        guess = relay_fopdt(ku, p.tu_s, gain_c)
    except ValueError:
        guess = Fopdt(gain_c, p.tu_s, p.tu_s / 4.0)
    return guess._replace(delay_s=max(guess.delay_s - r.switch_delay_s, 0.05 * p.tu_s))


def fit_points(model: str, points: Sequence[RelayPoint], ambient_c: float, *, power_w: float | None = None,
               segment: Segment | None = None, fixed: dict[str, float] | None = None,
               start: dict[str, float] | None = None, loss: str = "linear",
               on_evaluation: Callable[[], None] | None = None) -> FitResult:
    """Fit a model to relay points (and to a status trace, if given: each reading counted with the
    scatter of a printed extreme); ambient_c held; power_w and ``fixed`` held for lumped models;
    ``start`` overrides start values of fitted parameters. loss "radiating" (a lumped model): the
    radiation-like term too, its area fitted at RADIATING_EMISSIVITY (tools/ident/fit.py), the relay
    cycles on the plant linearised at their target (tools/ident/relay_loop.py ``tangent_plant``)."""
    if not points:
        raise NotFittable("no printed relay cycle with its period and swing to fit")
    radiating = loss == "radiating"
    held = {**HELD[model], "ambient_c": float(ambient_c), **({"emissivity": RADIATING_EMISSIVITY} if radiating else {}),
            **(fixed or {})}
    if power_w is not None and model in LUMPED_MODELS:
        held["power_w"] = float(power_w)
    fitted = [name for name in FITTED[model] + ((RADIATING_PARAM,) if radiating else ()) if name not in held]
    guess = {k: v for k, v in {**start_values(model, fopdt_guess(points, ambient_c), held),
                                RADIATING_PARAM: RADIATING_START_M2}.items() if k in fitted}
    start = {**guess, **{k: v for k, v in (start or {}).items() if k in guess}}
    sigma_trace_c = CYCLE_SCATTER_SWING_REL * float(np.mean([p.swing_c for p in points])) / math.sqrt(2.0)
    seen = None
    if segment is not None:
        seen = np.ones(len(segment.t_s), bool) if segment.observed is None else segment.observed
        start["initial_c"] = float(segment.temp_c[0])

    def residuals(p: dict[str, float]) -> np.ndarray:
        values = {**held, **p}
        parts = [point_residuals(model_spec(model, values), ambient_c, points)]
        if segment is not None:
            sim = model_response(model, values, segment.t_s, segment.duty)
            parts.append((sim - segment.temp_c)[seen] / sigma_trace_c)
        return np.concatenate(parts)

    est = least_squares_fit(residuals, start, bounds={"delay_s": (0.0, math.inf),
                                                      "sensor_responsiveness_per_s":
                                                          (0.0, MAX_SENSOR_RESPONSIVENESS_PER_S),
                                                      RADIATING_PARAM: RADIATING_BOUNDS_M2},
                            known_sigma=True, on_evaluation=on_evaluation)
    params, std = est.values, est.std_errors
    if model == "sopdt" and {"lag1_s", "lag2_s"} <= params.keys() and params["lag2_s"] > params["lag1_s"]:  # the two lags are interchangeable
        for d in (params, std):
            d["lag1_s"], d["lag2_s"] = d["lag2_s"], d["lag1_s"]
    if segment is None:
        held.setdefault("initial_c", points[0].relay.target_c)
    return FitResult(model, params, std, held, est.residuals_c, loss, evidence="relay results" if segment is None
                     else "relay results and status trace")
