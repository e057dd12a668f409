"""The tuning problem a user describes: a plant (a preset, or the plants a log allows), a target, a
controller, a loop, and the ensemble the plant's source allows.

    source = log_source("klippy.log", LogFitOptions(heater="extruder"))   # or preset_source("hotend")
    problem = build_problem(source, controller="pid")                     # the log's loop and target
    result, proof = default_tune(problem, source.printer)                  # tools/tuning/answer.py: the answer

A preset states no spread: its lag and loss terms get ``--spread`` (tools/tuning/ensemble.py). A log
gives every plant it allows (tools/tuning/allowed.py: the structures that fit about as well as the
best, each open parameter profiled, each plant replaying the log's own numbers), each at the ambient
it was fitted at; the printer's own gains where the log states them (tools/tuning/reference.py); the
loop its printer runs and the target it ran at. The ADC noise of a log's members is its own reading
noise where its trace shows it (at the target, through the sensor chain), else ``DEFAULT_NOISE_LSB``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tools.ident.fit import reading_noise_c
from tools.ident.log_fit import BED, LogFit, LogFitOptions, fit_log
from tools.ident.plausible import ROOM_C
from tools.logs import Log, M303Log, PlainLog, StatsLog, load_log
from tools.tuning.controllers import resolve_controller
from tools.tuning.allowed import Allowed, AllowedPlant, allowed_plants, degenerate, heater_settings
from tools.tuning.defaults import BED_TARGET_C, HOTEND_TARGET_C
from tools.tuning.ensemble import (
    DEFAULT_NOISE_LSB,
    DEFAULT_SPREAD,
    DEFAULT_STATISTIC,
    GROUPS,
    Uncertain,
    corner_ensemble,
    plant_ensemble,
    preset_spread,
)
from tools.tuning.evaluate import AMBIENT_C, Problem, default_scenario, full_power_time_s, heater_of
from tools.tuning.reference import PrinterGains, from_log
from tools.tuning.tuner import Step
from tools.validation.compare import HeaterInfo, Unusable, heatup_windows, overlaps
from tools.validation.m303_compare import twin_noise_lsb
from twin.limits import UserError
from twin.plants import SPECS, Spec

REACH_SHARE = 0.8  # a log without a target, whose heater cannot reach the default: 80 % of its demonstrated rise


@dataclass(frozen=True)
class Source:
    """Where a plant comes from: its name, spec, heater kind, ambient, what may vary; for a log, the plants it
    allows, the best fit's details, the printer's own gains, the firmware and target it ran."""

    name: str
    spec: Spec
    is_bed: bool
    ambient_c: float
    spread: tuple[Uncertain, ...]
    build: Callable[..., Spec] | None = None  # a corner's spec from its changes (a fit's spec_with)
    noise_lsb: float | None = None  # what the log's readings show, at the target; None: not measured
    fitted: LogFit | None = None
    plants: tuple[tuple[str, Spec, float], ...] = ()  # a log's: (label, spec, ambient_c), the best fit first
    allowed: Allowed | None = None
    printer: PrinterGains | None = None  # the gains the log states the printer runs
    loop: str = "marlin"  # the loop the log's printer runs
    target_c: float | None = None  # the target the log ran at, where it says
    reach_c: float | None = None  # the hottest reading of the fitted data: what the heater surely reaches
    klipper: HeaterInfo | None = None  # a klippy.log's heater settings


def preset_source(name: str, spread: float = DEFAULT_SPREAD) -> Source:
    """A twin/plants.py preset, its lag and loss terms spread +-``spread``; UserError names a bad preset."""
    if name not in SPECS:
        raise UserError(f"--plant {name!r}: valid presets: {', '.join(SPECS)}")
    spec = SPECS[name]
    return Source(name, spec, heater_of(name) == "bed", AMBIENT_C, preset_spread(spec, spread) if spread else ())


def log_source(path: str | Path, options: LogFitOptions | None = None, on_step: Step | None = None,
               ensemble: bool = True) -> Source:
    """``source_of`` the log at path."""
    return source_of(load_log(path), Path(path).name, options, on_step, ensemble)


def source_of(log: Log, name: str, options: LogFitOptions | None = None, on_step: Step | None = None,
              ensemble: bool = True) -> Source:
    """A log fitted as twin-fit fits it, with every plant it allows (tools/tuning/allowed.py; ``ensemble``
    False: the fit alone), the gains it states, the firmware and target it ran; ValueError (NotFittable)
    with the reason for a log that cannot support a tune. ``on_step`` reports progress."""
    options = options or LogFitOptions()
    if ensemble:
        return allowed_source(log, allowed_plants(log, name, options, on_step), options)
    fitted = fit_log(log, options)
    plant = degenerate(AllowedPlant(fitted.result.model, fitted, 0.0))
    if plant.dropped:
        return allowed_source(log, Allowed(name, fitted.heater, fitted, [], [plant]), options)
    return _with_log(fitted_source(fitted, name), log, fitted, [plant], options)


class NoModel(ValueError):
    """A log that reads and fits but allows no plant (``Allowed.why_none``): no model to tune on. It carries
    the plants considered and the gains the log states (None: none), for a verdict without a model."""

    def __init__(self, allowed: Allowed, printer: PrinterGains | None):
        super().__init__(f"{allowed.log_name}: the twin cannot tune from it: {allowed.why_none()}")
        self.allowed, self.printer = allowed, printer


def allowed_source(log: Log, allowed: Allowed, options: LogFitOptions | None = None) -> Source:
    """The source of the plants a log allows; NoModel where there are none."""
    if not allowed.members:
        entry = (options or LogFitOptions()).segment if isinstance(log, list) else None
        raise NoModel(allowed, from_log(log, allowed.heater, entry))
    best = allowed.best
    source = replace(fitted_source(best, allowed.log_name), allowed=allowed)
    return _with_log(source, log, best, allowed.members, options or LogFitOptions())


def _with_log(source: Source, log: Log, best: LogFit, members: list[AllowedPlant], options: LogFitOptions) -> Source:
    entry = options.segment if isinstance(log, list) else None
    loop = "marlin" if isinstance(log, (M303Log, PlainLog)) else "klipper"
    reach_c = float(np.max(best.segment.temp_c)) if best.segment is not None else None
    return replace(source, plants=tuple((p.label, p.result.spec(), _room(p.ambient_c)) for p in members),
                   printer=from_log(log, best.heater, entry), loop=loop, target_c=log_target_c(log, best),
                   klipper=heater_settings(log, best.heater), reach_c=reach_c)


def _room(ambient_c: float) -> float:
    """A fitted ambient the tune can run at: within a room (the spread still spans the fitted value)."""
    return min(max(ambient_c, ROOM_C[0]), ROOM_C[1])


def log_target_c(log, fitted: LogFit) -> float | None:
    """The target the log's heater ran at: a relay's target (as the fit found it), else the target of the
    fitted heat-up."""
    if fitted.target_c is not None:
        return fitted.target_c
    if fitted.result.anchor_c is not None:
        return fitted.result.anchor_c
    if isinstance(log, StatsLog) and fitted.segment is not None:
        try:
            _, windows = heatup_windows(log, fitted.heater)
        except Unusable:
            return None
        seg = fitted.segment
        own = [w for w in windows if overlaps(w, seg)]
        return float((own or windows)[0].target_c[-1]) if windows else None
    return None


def fitted_source(fitted: LogFit, log_name: str) -> Source:
    """The source of a fitted log (twin-fit's own fit); ValueError for a fit that cannot support a tune."""
    if reason := fitted.degenerate:
        raise ValueError(f"{log_name}: the fit cannot support a tune: {reason}")
    result = fitted.result
    spread = tuple(Uncertain(r.name, r.low, r.high, r.source) for r in result.spread() if r.name in GROUPS)
    residuals = fitted.trace_residuals_c()
    noise_c = reading_noise_c(residuals) if result.evidence == "trace" and residuals.size > 2 else None
    name = f"{log_name} ({result.model}, {result.evidence}, RMSE {result.rmse_c:.2f} C)"
    ambient_c = result.ambient_c
    if result.identification().get("ambient_c") != "identified" and not ROOM_C[0] <= ambient_c <= ROOM_C[1]:
        # a fitted ambient the data do not identify, outside any room: the tune runs at the nearest room
        # temperature (the spread still spans the fitted value)
        ambient_c = _room(ambient_c)
        name += f", ambient {ambient_c:g} C (the fit's {result.ambient_c:.3g} C is not identified)"
    return Source(name, result.spec(), fitted.heater == BED, ambient_c, spread, result.spec_with, noise_c, fitted)


def default_target_c(source: Source) -> float:
    """A heater's default target (HOTEND_TARGET_C, BED_TARGET_C); for a log that states none and whose
    heater cannot reach it at full power (a low-power test rig), REACH_SHARE of the way from ambient to the
    hottest reading the log shows, in whole degrees: a target its heater holds with power to spare."""
    default = BED_TARGET_C if source.is_bed else HOTEND_TARGET_C
    if source.reach_c is None:
        return default
    try:
        full_power_time_s(source.spec, source.ambient_c, default)
    except ValueError:
        return float(math.floor(source.ambient_c + REACH_SHARE * (source.reach_c - source.ambient_c)))
    return default


def build_problem(source: Source, target_c: float | None = None, controller: str = "pid", loop: str | None = None,
                  noise_lsb: float | None = None, statistic: str = DEFAULT_STATISTIC, spread: bool = True) -> Problem:
    """The problem on a source: the default scenario at its ambient (the target given, else the log's, else
    the heater's default), the controller of its heater, the loop given (else the log's), and (but on the
    idealised loop) the ensemble: the plants a log allows, or a preset's corners, with ADC noise
    (``noise_lsb``; None: the log's own, else the default); ``spread=False``: the nominal plant alone."""
    loop = loop or source.loop
    target = target_c if target_c is not None else source.target_c if source.target_c is not None else \
        default_target_c(source)
    if not target > source.ambient_c:
        raise UserError(f"--target {target:g}: a heater tune needs a target above the ambient "
                         f"{source.ambient_c:g} C")
    try:
        scenario = default_scenario(source.spec, target, source.ambient_c,
                                    world_inputs=all(spec.world_inputs for _, spec, _ in source.plants))
    except ValueError as exc:
        raise UserError(f"--target {target:g}: {exc}") from None
    space = resolve_controller(controller, "bed" if source.is_bed else "hotend")
    ensemble = None
    if loop != "ideal":  # the papers' loop is noiseless arithmetic on the nominal model
        noise = noise_lsb if noise_lsb is not None else \
            DEFAULT_NOISE_LSB if source.noise_lsb is None else twin_noise_lsb(source.noise_lsb, target)
        if source.plants:
            ensemble = plant_ensemble(source.plants if spread else source.plants[:1], noise, statistic)
        else:
            ensemble = corner_ensemble(source.spread if spread else (), noise, statistic, build=source.build)
    try:
        return Problem(source.name, source.spec, scenario, loop, space, ensemble, klipper=source.klipper)
    except ValueError as exc:
        raise UserError(f"--loop {loop}: {exc}") from None
