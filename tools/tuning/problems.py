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
from dataclasses import dataclass
from pathlib import Path

from tools.ident.fit import reading_noise_c
from tools.ident.log_fit import BED, LogFit, LogFitOptions, fit_log
from tools.ident.plausible import ROOM_C
from tools.logs import load_log
from tools.tuning.controllers import resolve_controller
from tools.tuning.ensemble import (
    DEFAULT_NOISE_LSB,
    DEFAULT_SPREAD,
    DEFAULT_STATISTIC,
    GROUPS,
    Uncertain,
    corner_ensemble,
    preset_spread,
)
from tools.tuning.evaluate import AMBIENT_C, Candidate, Problem, default_scenario, heater_of
from tools.tuning.objectives import heater_terms
from tools.tuning.tuner import DEFAULTS, TuneResult, tune
from tools.validation.m303_compare import twin_noise_lsb
from twin.plants import SPECS, Spec

HOTEND_TARGET_C, BED_TARGET_C = 210.0, 60.0
QUICK_BUDGET = 0  # quick_tune: the rules and the autotune, scored on the ensemble (no optimiser)
SUGGEST_SEARCH_BUDGET = 270  # suggest: where no rule holds, six generations of DE seeded with them


@dataclass(frozen=True)
class Source:
    """Where a plant comes from: its name, spec, heater kind, ambient, what may vary, and a fit's details."""

    name: str
    spec: Spec
    is_bed: bool
    ambient_c: float
    spread: tuple[Uncertain, ...]
    build: Callable[..., Spec] | None = None  # a corner's spec from its changes (a fit's spec_with)
    noise_lsb: float | None = None  # what the log's readings show, at the target; None: not measured
    fitted: LogFit | None = None


def preset_source(name: str, spread: float = DEFAULT_SPREAD) -> Source:
    """A twin/plants.py preset, its lag and loss terms spread +-``spread``; ValueError names a bad preset."""
    if name not in SPECS:
        raise ValueError(f"--plant {name!r}: valid presets: {', '.join(SPECS)}")
    spec = SPECS[name]
    return Source(name, spec, heater_of(name) == "bed", AMBIENT_C, preset_spread(spec, spread) if spread else ())


def log_source(path: str | Path, options: LogFitOptions | None = None) -> Source:
    """A log fitted as twin-fit fits it (tools/ident/log_fit.py): the very plant twin-fit prints, its ambient,
    its spread; ValueError (NotFittable) with the reason for a log that cannot support a tune."""
    return fitted_source(fit_log(load_log(path), options or LogFitOptions()), Path(path).name)


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
        ambient_c = min(max(ambient_c, ROOM_C[0]), ROOM_C[1])
        name += f", ambient {ambient_c:g} C (the fit's {result.ambient_c:.3g} C is not identified)"
    return Source(name, result.spec(), fitted.heater == BED, ambient_c, spread, result.spec_with, noise_c, fitted)


def build_problem(source: Source, target_c: float | None = None, controller: str = "pid", loop: str = "marlin",
                  noise_lsb: float | None = None, statistic: str = DEFAULT_STATISTIC, spread: bool = True) -> Problem:
    """The problem on a source: the default scenario at its ambient, the controller of its heater, and (but
    on the idealised loop) the ensemble of its spread with ADC noise (``noise_lsb``; None: the log's own,
    else the default)."""
    target = target_c if target_c is not None else (BED_TARGET_C if source.is_bed else HOTEND_TARGET_C)
    if not target > source.ambient_c:
        raise ValueError(f"--target {target:g}: a heater tune needs a target above the ambient "
                         f"{source.ambient_c:g} C")
    try:
        scenario = default_scenario(source.spec, target, source.ambient_c)
    except ValueError as exc:
        raise ValueError(f"--target {target:g}: {exc}") from None
    space = resolve_controller(controller, "bed" if source.is_bed else "hotend")
    ensemble = None
    if loop != "ideal":  # the papers' loop is noiseless arithmetic on the nominal model
        noise = noise_lsb if noise_lsb is not None else \
            DEFAULT_NOISE_LSB if source.noise_lsb is None else twin_noise_lsb(source.noise_lsb, target)
        ensemble = corner_ensemble(source.spread if spread else (), noise, statistic, build=source.build)
    try:
        return Problem(source.name, source.spec, scenario, loop, space, ensemble)
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
