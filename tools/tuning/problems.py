"""The tuning problem a user describes: a plant (a preset, or a log fitted exactly as twin-fit fits
it), a target, a controller, a loop, and the ensemble the plant's source allows.

    source = log_source("klippy.log", LogFitOptions(heater="extruder"))   # or preset_source("hotend")
    problem = build_problem(source, controller="pid", loop="marlin")
    suggestion = safe_best(quick_tune(problem))                            # what twin-fit suggests

A preset states no spread: its lag and loss terms get ``--spread`` (tools/tuning/ensemble.py). A
fitted plant carries what its data could not tell (tools/ident FitResult.spread(): standard errors,
plausible ranges of unidentified parameters with their sources), and its corner plants are built by
the fit itself (``spec_with``), so an ambient-anchored relay fit stays consistent. The ADC noise of
a fitted plant's members is the log's own reading noise where its trace shows it (at the target,
through the sensor chain), else ``DEFAULT_NOISE_LSB``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from tools.ident.fit import reading_noise_c
from tools.ident.log_fit import BED, LogFit, LogFitOptions
from tools.ident.plausible import ROOM_C
from tools.logs import M303Log, PlainLog, StatsLog, load_log
from tools.tuning.controllers import resolve_controller
from tools.tuning.allowed import Allowed, allowed_plants, heater_settings
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
from tools.tuning.evaluate import AMBIENT_C, Candidate, Problem, default_scenario, heater_of
from tools.tuning.objectives import heater_terms
from tools.tuning.reference import PrinterGains, from_log
from tools.tuning.tuner import DEFAULTS, TuneResult, tune
from tools.validation.compare import HeaterInfo, Unusable, heatup_windows, overlaps
from tools.validation.m303_compare import twin_noise_lsb
from twin.plants import SPECS, Spec

HOTEND_TARGET_C, BED_TARGET_C = 210.0, 60.0
QUICK_BUDGET = 0  # quick_tune: the rules and the autotune, scored on the ensemble (no optimiser)
SUGGEST_SEARCH_BUDGET = 270  # suggest: where no rule holds, six generations of DE seeded with them


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
    klipper: HeaterInfo | None = None  # a klippy.log's heater settings


def preset_source(name: str, spread: float = DEFAULT_SPREAD) -> Source:
    """A twin/plants.py preset, its lag and loss terms spread +-``spread``; ValueError names a bad preset."""
    if name not in SPECS:
        raise ValueError(f"--plant {name!r}: valid presets: {', '.join(SPECS)}")
    spec = SPECS[name]
    return Source(name, spec, heater_of(name) == "bed", AMBIENT_C, preset_spread(spec, spread) if spread else ())


def log_source(path: str | Path, options: LogFitOptions | None = None,
               on_step: Callable[[str, int], Callable[[], None]] | None = None) -> Source:
    """A log fitted as twin-fit fits it, with every plant it allows (tools/tuning/allowed.py), the gains it
    states, the firmware and target it ran; ValueError (NotFittable) with the reason for a log that cannot
    support a tune. ``on_step`` reports progress (allowed_plants)."""
    log = load_log(path)
    name = Path(path).name
    allowed = allowed_plants(log, name, options or LogFitOptions(), on_step)
    source = fitted_source(allowed.best, name)
    entry = (options.segment if options else None) if isinstance(log, list) else None
    klipper = heater_settings(log, allowed.heater)
    loop = "marlin" if isinstance(log, (M303Log, PlainLog)) else "klipper"
    return replace(source, plants=tuple((p.label, p.result.spec(), _room(p.ambient_c)) for p in allowed.members),
                   allowed=allowed, printer=from_log(log, allowed.heater, entry), loop=loop,
                   target_c=log_target_c(log, allowed.best), klipper=klipper)


def _room(ambient_c: float) -> float:
    """A fitted ambient the tune can run at: within a room (the spread still spans the fitted value)."""
    return min(max(ambient_c, ROOM_C[0]), ROOM_C[1])


def log_target_c(log, fitted: LogFit) -> float | None:
    """The target the log's heater ran at: a relay's target, else the target of the fitted heat-up."""
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


def build_problem(source: Source, target_c: float | None = None, controller: str = "pid", loop: str | None = None,
                  noise_lsb: float | None = None, statistic: str = DEFAULT_STATISTIC, spread: bool = True) -> Problem:
    """The problem on a source: the default scenario at its ambient (the target given, else the log's, else
    the heater's default), the controller of its heater, the loop given (else the log's), and (but on the
    idealised loop) the ensemble: the plants a log allows, or a preset's corners, with ADC noise
    (``noise_lsb``; None: the log's own, else the default); ``spread=False``: the nominal plant alone."""
    loop = loop or source.loop
    target = target_c if target_c is not None else source.target_c if source.target_c is not None else \
        (BED_TARGET_C if source.is_bed else HOTEND_TARGET_C)
    if not target > source.ambient_c:
        raise ValueError(f"--target {target:g}: a heater tune needs a target above the ambient "
                         f"{source.ambient_c:g} C")
    try:
        scenario = default_scenario(source.spec, target, source.ambient_c,
                                    world_inputs=all(spec.world_inputs for _, spec, _ in source.plants))
    except ValueError as exc:
        raise ValueError(f"--target {target:g}: {exc}") from None
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
        raise ValueError(f"--loop {loop}: {exc}") from None


def quick_tune(problem: Problem, budget: int = QUICK_BUDGET, seed: int = 0) -> TuneResult:
    """What twin-fit suggests: the rules and the firmware's autotune (and DE with a ``budget``), scored on the
    problem's ensemble by the heater objective; ``safe_best`` picks the answer."""
    return tune(problem, method="auto" if budget else "rules", budget=max(budget, 1), seed=seed)


def suggest(problem: Problem, seed: int = 0) -> Candidate | None:
    """twin-fit's gains: the safe best of the rules and the autotune; where each trips on some member,
    of a short DE seeded with them (``SUGGEST_SEARCH_BUDGET``); None if that trips too."""
    return safe_best(quick_tune(problem, seed=seed)) or safe_best(quick_tune(problem, SUGGEST_SEARCH_BUDGET, seed))


def safe_best(result: TuneResult) -> Candidate | None:
    """The best candidate from the plant itself (a rule, the autotune, a search: not the build's own
    defaults, tuned for another heater) that trips in no member of the ensemble, or None."""
    for candidate in result.ranked:
        if candidate.method != DEFAULTS and not heater_terms(candidate.run).tripped.any():
            return candidate
    return None
