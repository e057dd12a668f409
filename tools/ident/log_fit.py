"""Fit a log as twin-fit does: one function that twin-fit, twin-compare and twin-tune share, so that
a plant fitted to a log is the same plant everywhere (its ambient with it: ``FitResult.ambient_c``).

    fitted = fit_log(load_log(path), LogFitOptions(model=None))
    fitted.result.spec(), fitted.result.ambient_c, fitted.result.spread()

What each kind of log gives (tools/ident/segments.py, tools/ident/relay_points.py):
- a temperature trace (Klipper Stats, heattests, a plain CSV): its segments; one is fitted
  (two_node by default), decimated to MAX_FIT_SAMPLES;
- Marlin M303 console text: its printed cycles (relay points) and its 2 s status trace where it
  has one, fitted together (three_node by default; fopdt from the printed cycles alone: their Tu,
  extremes and bias steps identify its gain, lag and dead time); fit_cycles keeps the first cycles
  only (and the trace up to the last of them) for a prediction of the rest. The heater is the one the
  capture's lines say (tools/logs/m303.py), else the one its relay's target says (relay_heater); the
  target is the command's, else found in the data (relay_target_c); ``LogFit.target_c`` carries it,
  the temperature a tune of the fitted plant defaults to; ``loss`` radiating or auto where its status
  trace and relay target span RADIATING_SPAN_C (``radiating_span_c``), else UserError saying why;
- Klipper PID_CALIBRATE results: one entry's Tu and swing (fopdt with its static gain held, not
  identified: Klipper's relay prints no bias).
A segment without a heater step, or with a reading that never moves, is refused (NotFittable);
``LogFit.degenerate`` says when a fit identifies none of its model's lags.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tools.ident.fit import FITTED, LUMPED_MODELS, RADIATING_PARAM, RADIATING_SPAN_C, RADIATING_START_M2, fit_losses, fit_model
from tools.ident.plausible import heater_kind, plausible
from tools.ident.relay_loop import MARLIN_SWITCH_DELAY_S, KLIPPER_SWITCH_DELAY_S
from tools.ident.relay_points import (
    UNSAID_HEATER,
    RelayPoint,
    fit_points,
    heater_evidence,
    klipper_points,
    marlin_points,
    relay_heater,
)
from tools.ident.relay_trace import AMBIENT_PRIOR_C, ambient_reading_c, relay_target_c
from tools.ident.result import FitResult, aic
from tools.ident.segments import NotFittable, Segment, default_segment, log_segments
from tools.logs import MARLIN_POWER_MAX, Log, M303Log, PidCalibrateResults
from twin.limits import UserError
from twin.plants import BED_POWER_W, MPC_HEATER_POWER_W

BED = "heater_bed"
HEATER_NAMES = ("extruder", BED)  # the heaters a log here can hold
ASSUMED_POWER_W = {BED: BED_POWER_W}  # else MPC_HEATER_POWER_W; twin/plants.py says where both come from
MAX_FIT_SAMPLES = 5000  # a longer segment is decimated (Segment.decimated): a fit's cost follows its samples
# The radiating fit of relay data starts from the linear fit's values with each of these effective areas
# (m^2): near none (the linear fit itself) and twice a V6 block's; its optimiser can stall from either.
RADIATING_STARTS_M2 = (1e-5, RADIATING_START_M2)
MIN_READING_SPAN_C = 0.05  # a segment whose readings span less than this never moved: nothing to fit
# PID_CALIBRATE states no target: the temperatures the validation assumes (tools/validation/compare.py)
KLIPPER_TARGET_C = {"extruder": 200.0, BED: 60.0}


def assumed_power_w(heater: str) -> float:
    """The heater power a fit holds when none is given: a bed's or a hotend's (twin/plants.py)."""
    return ASSUMED_POWER_W.get(heater, MPC_HEATER_POWER_W)


@dataclass(frozen=True)
class LogFitOptions:
    """twin-fit's choices: None takes the default for the log."""

    model: str | None = None
    heater: str | None = None
    session: int | None = None
    segment: int | None = None  # a trace's segment, or a PID_CALIBRATE results file's entry
    ambient_c: float | None = None
    power_w: float | None = None
    loss: str = "linear"
    fit_cycles: int | None = None  # an M303 capture: fit its first cycles only
    target_c: float | None = None  # relay data: the relay's target, where the capture does not state it
    fixed: tuple[tuple[str, float], ...] = ()  # parameters held at these values (a profile of the fit)
    start: tuple[tuple[str, float], ...] = ()  # start values of fitted parameters (a refit from a fit's values)
    on_evaluation: Callable[[], None] | None = None  # called at each residual evaluation (a progress bar)


@dataclass(frozen=True)
class LogFit:
    """A fitted log: its heater, the segments on offer, the one chosen and the part of it fitted
    (decimated, or cut at the last fitted cycle), the relay points used, the fit, and notes for the
    reader (ambient, power, what was compared)."""

    heater: str
    segments: list[Segment]
    chosen: int | None
    result: FitResult
    points: list[RelayPoint] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    resolution_s: float = 0.0  # the shortest dead time the data can show (a trace's sample interval)
    compared: list[str] = field(default_factory=list)  # --loss auto: both losses' RMSE and AIC
    segment: Segment | None = None  # what was fitted of segments[chosen]
    target_c: float | None = None  # relay data: the relay's target (the temperature a tune defaults to)
    target_source: str = ""  # where target_c comes from: the M303 command, --target, or the data

    @property
    def degenerate(self) -> str | None:
        return self.result.degenerate()

    def trace_residuals_c(self) -> np.ndarray:
        """The fitted model against the fitted segment's compared readings (C; empty without a trace)."""
        seg = self.segment
        if seg is None:
            return np.empty(0)
        seen = np.ones(len(seg.t_s), bool) if seg.observed is None else seg.observed
        return (self.result.simulate(seg.t_s, seg.duty) - seg.temp_c)[seen]


def check_excitation(seg: Segment) -> None:
    """NotFittable for a segment that holds no dynamics: no heater step, or readings that never move."""
    if np.ptp(seg.duty) == 0:
        raise NotFittable(f"{seg.label}: no heater step: the duty stays at {seg.duty[0]:g} throughout")
    if np.ptp(seg.temp_c) < MIN_READING_SPAN_C:
        raise NotFittable(f"{seg.label}: the reading never moves (it stays at {seg.temp_c[0]:g} C)")


def _ambient(log: Log, options: LogFitOptions) -> tuple[float | None, str | None, bool]:
    """(ambient to hold or None to fit it, a note, whether it is assumed): given, an M303 capture's
    idle heater, a room for relay data without one; a trace's own fit otherwise."""
    if options.ambient_c is not None:
        return options.ambient_c, None, False
    if isinstance(log, M303Log) and (ambient := ambient_reading_c(log)) is not None:
        return ambient, f"ambient {ambient:g} C: the idle heater reads it (--ambient sets it)", False
    if isinstance(log, (M303Log, list)):
        return AMBIENT_PRIOR_C, (f"ambient {AMBIENT_PRIOR_C:g} C: a room, assumed (relay data near their target "
                                 "cannot tell; --ambient sets it)"), True
    return None, None, False


def _power(model: str, heater: str, options: LogFitOptions) -> tuple[float | None, str | None]:
    if model not in LUMPED_MODELS:
        return None, None
    if options.power_w is not None:
        return options.power_w, None
    power_w = assumed_power_w(heater)
    return power_w, f"power_w {power_w:g} W assumed (the log fixes P/C and P/A, not the wattage)"


def _finish(result: FitResult, heater: str, ambient_assumed: bool, anchor_c: float | None) -> FitResult:
    assumed = result.assumed + (("ambient_c",) if ambient_assumed else ())
    return dataclasses.replace(result, heater=heater, assumed=assumed, anchor_c=anchor_c)


def _trace_fit(log: Log, options: LogFitOptions) -> LogFit:
    heater, segments = log_segments(log, options.heater, options.session)
    chosen = default_segment(segments) if options.segment is None else options.segment
    if not 0 <= chosen < len(segments):
        raise UserError(f"--segment {chosen}: the segments are 0..{len(segments) - 1}")
    seg = segments[chosen].decimated(MAX_FIT_SAMPLES)
    check_excitation(seg)
    model = options.model or ("three_node" if isinstance(log, M303Log) else "two_node")
    ambient_c, ambient_note, assumed = _ambient(log, options)
    power_w, power_note = _power(model, heater, options)
    series = (model, seg.t_s, seg.temp_c, seg.duty, ambient_c)
    compared = []
    if options.loss == "auto":
        choice = fit_losses(*series, power_w=power_w, observed=seg.observed, fixed=dict(options.fixed))
        result = choice.fits[choice.kept]
        compared = [f"{name} RMSE {fit.rmse_c:.2f} C, AIC {aic(fit):.0f}" for name, fit in choice.fits.items()]
    else:
        result = fit_model(*series, power_w=power_w, observed=seg.observed, loss=options.loss,
                           fixed=dict(options.fixed), start=_start(options, model, options.loss),
                           on_evaluation=options.on_evaluation)
    notes = [n for n in (ambient_note, power_note) if n]
    return LogFit(heater, segments, chosen, _finish(result, heater, assumed, None), notes=notes,
                  resolution_s=float(np.median(np.diff(seg.t_s))), compared=compared, segment=seg)


def _m303_trace(log: M303Log, options: LogFitOptions) -> tuple[str, str, list[Segment], int | None]:
    """The heater and how it is known (--heater, the capture's lines, else its relay's target), the
    status-trace segments and the one to fit (--segment, else the most at full power)."""
    try:
        heater, segments = log_segments(log, options.heater)
    except NotFittable:
        heater, why = (options.heater, "as --heater says") if options.heater else relay_heater(log)
        return heater, why, [], None
    chosen = default_segment(segments) if options.segment is None else options.segment
    if not 0 <= chosen < len(segments):
        raise UserError(f"--segment {chosen}: the segments are 0..{len(segments) - 1}")
    why = "as --heater says" if options.heater else heater_evidence(log, heater) or UNSAID_HEATER
    return heater, why, segments, chosen


def _m303_points(log: M303Log, heater: str, trace: Segment | None,
                 target: float | None) -> tuple[list[RelayPoint], float | None, str]:
    """The printed cycles as relay points at the relay's target, the target and where it comes from: --target,
    else the trace's, else the command's or the cycles' (relay_target_c); NotFittable where there are no
    cycles and no trace either."""
    key = "B" if heater == BED else "T"
    printed = [c for c in log.cycles_of(key) if c.tu_s and c.min_c is not None and c.max_c is not None]
    repetier = log.power_max != MARLIN_POWER_MAX
    relay = bool(printed) and not repetier
    if not relay and trace is None:
        why = ("Repetier's relay has its own levels and rules: its cycles are not read as relay points" if repetier
               else f"{len(printed)} printed cycles with Tu, min and max")
        raise NotFittable(f"autotune output with {len(log.cycles)} relay cycles and no status trace to fit; {why}")
    if target is not None:
        found: tuple[float, str] | None = (target, "as --target says")
    elif trace is not None and math.isfinite(trace.target_c):
        found = (trace.target_c, trace.target_source)
    else:
        found = relay_target_c(log, key, printed[0].line_no) if printed else None
    target_c, source = found if found is not None else (None, "")
    return marlin_points(log, heater, target_c) if relay else [], target_c, source


def _first_cycles(points: list[RelayPoint], trace: Segment | None,
                  count: int) -> tuple[list[RelayPoint], Segment | None, str]:
    """The first count points, the trace up to the last of them, and a note saying so."""
    if not 0 < count <= len(points):
        raise UserError(f"--fit-cycles {count}: the capture prints {len(points)} cycles with Tu")
    points = points[:count]
    trace = None if trace is None else trace.before_line(points[-1].line_no + 1)
    if trace is not None and not (trace.observed is None or trace.observed.any()):
        trace = None  # no reading of the trace before the last fitted cycle is compared
    return points, trace, (f"fitted on the first {count} printed cycles"
                           + (f" and the status trace up to line {points[-1].line_no}" if trace is not None else ""))


def _m303_fit(log: M303Log, options: LogFitOptions) -> LogFit:
    """The printed cycles, with the status trace if the capture has one, fitted together."""
    heater, heater_why, segments, chosen = _m303_trace(log, options)
    trace = None if chosen is None else segments[chosen]
    points, target_c, target_source = _m303_points(log, heater, trace, options.target_c)
    notes = [f"{heater}: {heater_why}"]
    if target_c is not None:
        notes.append(f"relay target {target_c:g} C: {target_source}")
    if options.fit_cycles is not None:
        points, trace, note = _first_cycles(points, trace, options.fit_cycles)
        notes.append(note)
    if not points:
        fitted = _trace_fit(log, options)
        return dataclasses.replace(fitted, notes=notes + fitted.notes, target_c=target_c, target_source=target_source)
    model = options.model or ("three_node" if trace is not None else "fopdt")
    if options.loss != "linear":
        _check_radiating_span(options.loss, model, trace, target_c)
    ambient_c, ambient_note, assumed = _ambient(log, options)
    assert ambient_c is not None
    power_w, power_note = _power(model, heater, options)

    def fit(loss: str, start: dict[str, float] | None = None) -> FitResult:
        return fit_points(model, points, ambient_c, power_w=power_w, segment=trace, fixed=dict(options.fixed),
                          start={**(start or {}), **(_start(options, model, loss) or {})}, loss=loss,
                          on_evaluation=options.on_evaluation)

    result, compared = fit("linear"), []
    if options.loss != "linear":  # from the linear fit's values with a small area and a large one: the better
        radiating = [fit("radiating", {**result.params, RADIATING_PARAM: area_m2}) for area_m2 in RADIATING_STARTS_M2]
        fits = {"linear": result, "radiating": min(radiating, key=lambda f: f.rmse_c)}
        result = fits["radiating"] if options.loss == "radiating" else min(fits.values(), key=aic)
        if options.loss == "auto":
            compared = [f"{name} RMS {f.rmse_c:.2f} (in units of the scatter), AIC {aic(f):.0f}"
                        for name, f in fits.items()]
    notes += [n for n in (ambient_note, power_note) if n]
    return LogFit(heater, segments, chosen if trace is not None else None,
                  _finish(result, heater, assumed, target_c), points, notes, MARLIN_SWITCH_DELAY_S,
                  compared=compared, segment=trace, target_c=target_c, target_source=target_source)


def radiating_span_c(trace: Segment | None, target_c: float | None) -> float:
    """What an M303 capture spans for a radiating loss: its status trace's readings and the relay's target (the
    printed cycles sit there), lowest to highest; 0 without a trace (the cycles alone sit at one temperature)."""
    if trace is None:
        return 0.0
    readings = trace.temp_c if trace.observed is None else trace.temp_c[trace.observed]
    high_c = max(float(np.max(readings)), target_c if target_c is not None else -math.inf)
    return high_c - float(np.min(readings))


def _check_radiating_span(loss: str, model: str, trace: Segment | None, target_c: float | None) -> None:
    """UserError where --loss radiating or auto cannot be fitted to an M303 capture: a model without a loss
    term, or a capture spanning under RADIATING_SPAN_C (radiation and a linear loss look alike there)."""
    span_c = radiating_span_c(trace, target_c)
    if span_c < RADIATING_SPAN_C:
        what = ("it has no status trace, and its printed cycles sit at one temperature" if trace is None else
                f"its status trace and relay target span {span_c:.0f} C")
        raise UserError(f"--loss {loss}: this M303 capture cannot tell a radiating loss from a linear one: {what} "
                        f"(it takes {RADIATING_SPAN_C:g} C or more)")
    if model not in LUMPED_MODELS:
        raise UserError(f"--loss {loss}: needs --model two_node or three_node: {model} has no heat-loss term")


def _pid_results_fit(results: PidCalibrateResults, options: LogFitOptions) -> LogFit:
    """One PID_CALIBRATE entry (--segment, default the first) as a relay point at its heater's assumed target."""
    chosen = 0 if options.segment is None else options.segment
    if not 0 <= chosen < len(results):
        raise UserError(f"--segment {chosen}: the entries are 0..{len(results) - 1}")
    entry = results[chosen]
    heater = options.heater or entry.heater or "extruder"
    target_c = options.target_c or KLIPPER_TARGET_C[BED if heater_kind(heater) == "bed" else "extruder"]
    model = options.model or "fopdt"
    if model != "fopdt":
        raise UserError(f"--model {model}: a PID_CALIBRATE result (Tu and swing, no bias) fits fopdt only")
    ambient_c, ambient_note, assumed = _ambient(results, options)
    assert ambient_c is not None
    points = klipper_points([entry], target_c)
    gain_c = _nominal_gain_c(heater)
    result = fit_points("fopdt", points, ambient_c, fixed={"gain_c": gain_c, **dict(options.fixed)},
                        start=_start(options, "fopdt", "linear"), on_evaluation=options.on_evaluation)
    result = dataclasses.replace(result, assumed=("gain_c",))
    notes = [f"entry {chosen}: {entry.source or 'no source'}; Tu {entry.tu_s:.4g} s, swing {entry.peak_to_peak_c:.3g} C "
             f"at a target of {target_c:g} C" + (" (assumed: a result states none; --target sets it)"
                                                  if options.target_c is None else ""),
             f"gain_c held at {gain_c:.4g} C: Klipper's relay prints no bias, so the static gain is not identified"]
    notes += [n for n in (ambient_note,) if n]
    return LogFit(heater, [], None, _finish(result, heater, assumed, target_c), points, notes,
                  KLIPPER_SWITCH_DELAY_S, target_c=options.target_c,
                  target_source="as --target says" if options.target_c is not None else "")


def _start(options: LogFitOptions, model: str, loss: str) -> dict[str, float]:
    """The start values options give that the model (with that loss) fits, the held ones left out."""
    fitted = {*FITTED[model], "initial_c", "ambient_c", *((RADIATING_PARAM,) if loss == "radiating" else ())}
    held = dict(options.fixed)
    return {name: value for name, value in options.start if name in fitted and name not in held}


def _nominal_gain_c(heater: str) -> float:
    """The geometric middle of a heater kind's plausible static gain (tools/ident/plausible.py)."""
    r = plausible("gain_c", heater, 1.0)
    return math.sqrt(r.low * r.high)


def fit_log(log: Log, options: LogFitOptions | None = None) -> LogFit:
    """Fit a log as twin-fit does (module docstring); NotFittable or ValueError say why it cannot be."""
    options = options or LogFitOptions()
    if options.fit_cycles is not None and not isinstance(log, M303Log):
        raise UserError("--fit-cycles needs an M303 capture (printed relay cycles)")
    if isinstance(log, M303Log):
        return _m303_fit(log, options)
    if isinstance(log, list):
        return _pid_results_fit(log, options)
    return _trace_fit(log, options)
