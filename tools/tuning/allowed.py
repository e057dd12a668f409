"""The plants a log allows: the ensemble a tune from a log runs on and its proof holds on.

One fit of one structure is one answer to "what plant made this log"; the data usually allow several.

1. Structures: every model that applies to the log (``structures``): fopdt, sopdt, two_node, three_node
   for a trace or an M303 capture; with a trace that spans RADIATING_SPAN_C or more (an M303 capture:
   its status trace and its relay's target, tools/ident/log_fit.py ``radiating_span_c``), two_node and
   three_node with the radiating loss too (below that span radiation and a linear loss cannot be told
   apart); fopdt alone for a PID_CALIBRATE result (two numbers, the gain held).
2. Evidence: Akaike's criterion of each fit against the best (``evidence``). Residuals already divided
   by their scatter (relay results, and a status trace fitted with them) give sum(r^2) + 2 k. A trace's
   residuals in C give n_eff ln(SSE / n) + 2 k, where n_eff = n (1 - rho) / (1 + rho) shrinks the sample
   count by the best fit's lag-1 autocorrelation rho: a log's residuals are correlated (model error, a
   1 Hz pwm), and counted as n independent samples every small gain in SSE would look decisive. A fit
   is kept when it is within EVIDENCE_MARGIN (6) of the best: relative likelihood exp(-6/2) = 1/20.
3. Profiles: a fit that identifies none of its model's lags (``FitResult.degenerate``) is no member: its
   lags could be anything; it is dropped with that reason, and its profiles stand in for it. Each
   parameter a kept fit leaves open (``FitResult.spread()``: not identified, assumed, or
   poorly identified) is fixed at each end of its range and the others refitted (``profiles``); an end
   the evidence excludes is tried once more halfway (geometric mean) to the fitted value. A
   profile counts the parameter it holds in k, so holding a parameter earns no credit.
4. Replay: a member is kept only if the twin, replaying what the log recorded, reproduces the log's
   own numbers (``replay``): an M303 capture's printed cycles by the twin's own M303 at the same
   target (mean Tu and swing within tools/validation/m303_compare.py GOALS: 10 % / 25 % with a status
   trace, 15 % / 30 % from the result lines), a PID_CALIBRATE result by the twin's PID_CALIBRATE at
   its target (Tu and swing, the result lines' goals), a Klipper Stats heater by the twin's closed loop
   with the printer's own gains and settings through the logged targets of a heat-up (tools/validation
   /compare.py goals: heat-up time 10 %, overshoot 1.5 C, hold 1 C RMS), an open-loop trace by its
   RMSE (3 C, the open-loop goal); so is a Stats heater without a heat-up under the printer's own loop
   (a log of PID_CALIBRATE alone: its relay, not the PID, drove the heater). An M303 replay that
   misses says whether the fit itself misses the printed cycles (tools/validation/m303_bias.py
   ``own_relay_note``: the plant's own relay at their levels).
5. The printer's own calibration: where a klippy.log's saved gains are PID_CALIBRATE's
   (tools/tuning/calibration.py: Kd Ki = Kp^2 / 4 within their printed rounding), the relay's Ku and Tu
   they imply are evidence the 1 Hz Stats trace lacks (it cannot show the sub-second lags that set a
   hotend's relay period). Each plant that replays the log runs the port's PID_CALIBRATE with the heater's
   settings at the ends of docs/validation.md's band (tools/tuning/relay_evidence.py); one whose Tu misses
   the saved Tu by more than 15 % (or Ku by more than 30 %) everywhere in the band is dropped, the reason
   naming both. Where some miss, each structure that replayed is refitted with the lag that sets its relay
   period held where the period is the saved one (tools/tuning/relay_refit.py), then replayed and checked
   as the others; its trace evidence is not compared (the relay's evidence chose it). ``Allowed.calibration``
   says whether the check ran and what it found.
6. Alike members fold: one whose FOPDT equivalent (gain, time constant, dead time) lies within
   ALIKE_REL of a member kept before it adds no plant the loop behaves differently on.

The fits and the replays run in forked worker processes (tools/forked.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tools.forked import forked_map
from tools.ident.fit import LUMPED_MODELS, MODELS, RADIATING_SPAN_C
from tools.ident.fopdt import fopdt_equivalent
from tools.ident.log_fit import LogFit, LogFitOptions, fit_log, radiating_span_c
from tools.ident.lsq import LINEAR_PARAMS
from tools.ident.result import FitResult
from tools.ident.segments import NotFittable
from tools.logs import Log, M303Log, StatsLog
from firmware_port.klipper.heater import PID_PARAM_BASE
from tools.tuning import relay_evidence, relay_refit
from tools.tuning.calibration import SavedCalibration, from_config
from tools.tuning.relay_evidence import RelayCheck
from tools.validation import compare, m303_compare
from tools.validation.m303_bias import own_relay_note
from twin.klipper_twin import KlipperTwin, extruder_setup
from twin.plants import Plant

EVIDENCE_MARGIN = 6.0  # Akaike units: relative likelihood exp(-margin / 2) = 1/20 of the best fit's
ALIKE_REL = 0.02  # members whose FOPDT equivalents agree within this fold into one
END_REL = 0.01  # a range end this close to the fitted value is the fit itself


@dataclass(frozen=True)
class Replay:
    """What the twin on a plant predicts for the log's own numbers: (quantity, log, twin, goal) rows."""

    what: str
    rows: tuple[tuple[str, float, float, str], ...]
    passed: bool
    note: str = ""

    def text(self) -> str:
        cells = "; ".join(f"{name} {log:.4g} / {twin:.4g} ({goal})" for name, log, twin, goal in self.rows)
        return f"{self.what}: {cells} (log / twin){': ' + self.note if self.note else ''}"


@dataclass(frozen=True)
class AllowedPlant:
    """One fit considered: its label, the fit, its evidence against the best, its replay, why it is
    not a member (None: it is), and how many parameters it holds (0: a structure's own fit, 1: a profile)."""

    label: str
    fitted: LogFit
    delta: float
    replay: Replay | None = None
    dropped: str | None = None
    held: int = 0
    calibration: RelayCheck | None = None  # its PID_CALIBRATE against the printer's saved one, where checked

    @property
    def result(self) -> FitResult:
        return self.fitted.result

    @property
    def ambient_c(self) -> float:
        return self.result.ambient_c


@dataclass(frozen=True)
class Allowed:
    """The plants a log allows (members, the best fit first) and the fits it does not, with the reason."""

    log_name: str
    heater: str
    first: LogFit  # the default fit (twin-fit's), whether or not it is a member
    members: list[AllowedPlant]
    dropped: list[AllowedPlant] = field(default_factory=list)
    calibration: str = ""  # what the check against the printer's PID_CALIBRATE found ("": not a klippy.log)

    @property
    def best(self) -> LogFit:
        """The member of the best evidence; the default fit where no plant replays the log."""
        return self.members[0].fitted if self.members else self.first

    def why_none(self) -> str:
        """Why no plant is a member, in one line: every structure tried and why it is not one, and how many of
        their profiles were tried."""
        if not self.dropped:
            return "no fit"
        relays = [p.calibration for p in self.dropped if p.calibration is not None and not p.calibration.passed]
        if relays:
            return no_relay_reason(relays)
        tried = [p for p in self.dropped if not p.held]
        profiles = len(self.dropped) - len(tried)
        each = "; ".join(f"{p.label}: {p.dropped}" for p in tried)
        more = f"; and none of their {profiles} profiles is a member" if profiles else ""
        return f"no plant both fits it and replays it: {each}{more}"

    def lines(self) -> list[str]:
        """What twin-fit and twin-tune print: each member and each dropped fit, with its evidence and replay."""
        out = [f"the plants {self.log_name} allows ({len(self.members)} of {len(self.members) + len(self.dropped)} "
               f"fits considered; evidence: Akaike's criterion against the best, kept within {EVIDENCE_MARGIN:g}; "
               "each member replays the log):"]
        if self.calibration:
            out.append(f"  check against your PID_CALIBRATE: {self.calibration}")
        for plant in self.members:
            check = f"; {plant.calibration.text()}" if plant.calibration else ""
            delta = f"delta {plant.delta:.1f}" if math.isfinite(plant.delta) else "the trace's evidence not compared"
            out.append(f"  member {plant.label}: {delta}, "
                       f"{plant.replay.text() if plant.replay else 'no replay'}{check}")
        for plant in self.dropped:
            out.append(f"  dropped {plant.label}: {plant.dropped}")
        return out


# -- 1. structures ------------------------------------------------------------------------------------
def structures(log: Log, first: LogFit) -> list[tuple[str, str]]:
    """(model, loss) pairs that apply to the log (module docstring, 1)."""
    if isinstance(log, list):
        return [("fopdt", "linear")]
    pairs = [(model, "linear") for model in MODELS]
    seg = first.segment
    if isinstance(log, M303Log) and first.points:  # the relay's target counts: its printed cycles sit there
        span_c = radiating_span_c(seg, first.target_c)
    else:
        span_c = float(np.ptp(seg.temp_c)) if first.result.evidence == "trace" and seg is not None else 0.0
    if span_c >= RADIATING_SPAN_C:
        pairs += [(model, "radiating") for model in LUMPED_MODELS]
    return pairs


def _label(model: str, loss: str) -> str:
    return model + (", radiating" if loss == "radiating" else "")


# -- 2. evidence --------------------------------------------------------------------------------------
def _parameters(result: FitResult, held: int) -> int:
    return len(result.params) + held


def evidence(results: list[FitResult], held: list[int]) -> np.ndarray:
    """Each fit's criterion minus the best's (module docstring, 2); ``held``: parameters a profile holds."""
    k = np.array([_parameters(r, h) for r, h in zip(results, held)], float)
    sse = np.array([float(np.sum(np.square(r.residuals_c))) for r in results])
    if results[0].evidence != "trace":  # residuals in units of their scatter
        criterion = sse + 2.0 * k
    else:
        best = results[int(np.argmin(sse))].residuals_c
        n = len(best)
        rho = float(np.corrcoef(best[:-1], best[1:])[0, 1]) if n > 2 and np.std(best) > 0 else 0.0
        n_eff = float(np.clip(n * (1.0 - rho) / (1.0 + rho), k.max() + 2.0, n))
        criterion = n_eff * np.log(np.maximum(sse, 1e-300) / n) + 2.0 * k
    return criterion - criterion.min()


# -- 3. profiles --------------------------------------------------------------------------------------
def _profile_options(options: LogFitOptions, result: FitResult, name: str, value: float) -> LogFitOptions:
    """The options that refit ``result``'s structure with ``name`` held at ``value``, from its own values."""
    start = tuple((k, v) for k, v in result.params.items() if k != name)
    if name == "ambient_c":
        return dataclasses.replace(options, ambient_c=value, start=start)
    return dataclasses.replace(options, fixed=options.fixed + ((name, value),), start=start)


def profile_points(result: FitResult) -> list[tuple[str, float, float]]:
    """(parameter, fitted value, range end) for each end of each parameter the fit leaves open."""
    out = []
    for r in result.spread():
        value = result.values[r.name]
        for end in (r.low, r.high):
            if abs(end - value) > END_REL * max(abs(value), 1e-9):
                out.append((r.name, value, end))
    return out


def halfway(name: str, value: float, end: float) -> float:
    """The point halfway from a fitted value to a range end: geometric for the parameters fitted as
    logarithms, arithmetic for the others (tools/ident/lsq.py LINEAR_PARAMS)."""
    if name in LINEAR_PARAMS or value <= 0 or end <= 0:
        return (value + end) / 2.0
    return math.sqrt(value * end)


def _end_label(name: str, value: float, end: float, at: float) -> str:
    where = "low" if end < value else "high"
    part = "end" if at == end else "halfway to the end"
    return f"{name} {at:.4g} ({part} {where}, fitted {value:.4g})"


# -- 4. replay ----------------------------------------------------------------------------------------
def replay(log: Log, fitted: LogFit, info: compare.HeaterInfo | None) -> Replay:
    """The twin on a fitted plant against the log's own numbers (module docstring, 4)."""
    result = fitted.result
    if isinstance(log, M303Log) and fitted.points:
        try:
            row = m303_compare.replay_fit(log, fitted)
        except m303_compare.NoRelay as exc:
            return Replay("the twin's M303", (), False, str(exc))
        goal_tu, goal_swing = row.goals
        tu_goal = "on the 10 s relay floor: not scored" if row.floor else f"within {goal_tu:.0%}"
        return Replay(f"the twin's M303 at {result.anchor_c:g} C against the {row.log.cycles} printed cycles",
                      (("Tu s", row.log.tu_s, row.twin.tu_s, tu_goal),
                       ("swing C", row.log.swing_c, row.twin.swing_c, f"within {goal_swing:.0%}")), row.passed,
                      "" if row.passed else own_relay_note(fitted, row.goals))
    if isinstance(log, list) and fitted.points:
        return _pid_calibrate_replay(fitted)
    if isinstance(log, StatsLog) and info is not None:
        closed = _closed_loop_replay(log, fitted, info)
        if closed is not None:
            return closed
    residuals = fitted.trace_residuals_c()
    rmse = float(np.sqrt(np.mean(residuals ** 2))) if residuals.size else math.inf
    goal = compare.GOAL_OPEN_LOOP_RMSE_C
    return Replay("the plant under the logged duty", (("trace RMSE C", 0.0, rmse, f"at most {goal:g} C"),),
                  rmse <= goal)


def _pid_calibrate_replay(fitted: LogFit) -> Replay:
    point, result = fitted.points[0], fitted.result
    target_c = point.relay.target_c
    ambient_c = result.ambient_c
    twin = KlipperTwin([extruder_setup(Plant(result.model, result.spec(), ambient_c, ambient_c),
                                       max_power=point.relay.on_duty, max_temp_c=target_c + 50.0)])
    goal_tu, goal_swing = m303_compare.GOALS["results"]
    try:
        got = twin.pid_calibrate("extruder", target_c)
    except Exception as exc:  # noqa: BLE001 - a shutdown or a timeout: the plant cannot replay it
        return Replay("the twin's PID_CALIBRATE", (), False, f"did not finish: {exc}")
    tu_ok = abs(got.tu_s / point.tu_s - 1.0) <= goal_tu
    swing_ok = abs(got.peak_to_peak_c / point.swing_c - 1.0) <= goal_swing
    return Replay(f"the twin's PID_CALIBRATE at {target_c:g} C", (
        ("Tu s", point.tu_s, got.tu_s, f"within {goal_tu:.0%}"),
        ("swing C", point.swing_c, got.peak_to_peak_c, f"within {goal_swing:.0%}")), tu_ok and swing_ok)


def _closed_loop_replay(log: StatsLog, fitted: LogFit, info: compare.HeaterInfo) -> Replay | None:
    """The twin's closed loop through a heat-up of the log; None if the printer's loop drove none (a log of
    PID_CALIBRATE alone, whose relay moves the target between target and target - 5 C)."""
    try:
        _, windows = compare.heatup_windows(log, fitted.heater)
    except compare.Unusable as exc:
        return Replay("the twin's closed loop", (), False, str(exc))
    if not windows:
        return None
    seg = fitted.segment
    own = [w for w in windows if seg is not None and compare.overlaps(w, seg)]
    window = (own or windows)[0]
    r = compare.score_replay("", fitted.heater, fitted.result, "", info, window, bool(own))
    checks = r.checks
    return Replay(f"the twin's closed loop with the printer's gains, {window.label}", (
        ("heat-up s", r.log.heatup_s, r.twin.heatup_s, f"within {compare.GOAL_HEATUP_REL:.0%}"),
        ("overshoot C", r.log.overshoot_c, r.twin.overshoot_c, f"within {compare.GOAL_OVERSHOOT_C:g} C"),
        ("hold RMS twin-log C", 0.0, r.hold_rmse_c, f"at most {compare.GOAL_HOLD_RMSE_C:g} C")),
        all(checks.values()), "" if r.shutdown is None else f"the twin shut down: {r.shutdown.splitlines()[0]}")


# -- the ensemble -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Task:
    label: str
    options: LogFitOptions
    held: int


@dataclass(frozen=True)
class _End:
    """A range end of a parameter a kept structure leaves open, to profile."""

    structure: _Task
    result: FitResult
    name: str
    value: float
    end: float

    def task(self, at: float) -> _Task:
        """The refit with the parameter held at ``at`` (the end, or halfway to it)."""
        return _Task(f"{self.structure.label}: {_end_label(self.name, self.value, self.end, at)}",
                     _profile_options(self.structure.options, self.result, self.name, at), 1)


def _fit(log: Log) -> Callable[[_Task], LogFit | str]:
    def run(task: _Task) -> LogFit | str:
        try:
            return fit_log(log, task.options)
        except (NotFittable, ValueError) as exc:
            return str(exc)
    return run


def _judged(tasks: list[_Task], fits: list[LogFit | str], against: list[FitResult]) -> list[AllowedPlant | None]:
    """Each task's fit with its evidence against the best of ``against`` and of these fits (None where it
    failed), dropped where the evidence excludes it."""
    ok = [k for k, f in enumerate(fits) if isinstance(f, LogFit)]
    results = [fits[k].result for k in ok]  # type: ignore[union-attr]
    deltas = evidence(against + results, [0] * len(against) + [tasks[k].held for k in ok])[len(against):] \
        if ok else np.zeros(0)
    out: list[AllowedPlant | None] = [None] * len(tasks)
    for k, d in zip(ok, deltas):
        fitted = fits[k]
        assert isinstance(fitted, LogFit)
        out[k] = AllowedPlant(tasks[k].label, fitted, float(d), dropped=None if d <= EVIDENCE_MARGIN else
                              f"the evidence excludes it (delta {d:.1f} > {EVIDENCE_MARGIN:g})", held=tasks[k].held)
    return out


def degenerate(plant: AllowedPlant) -> AllowedPlant:
    """The plant dropped where its fit identifies none of its model's lags (module docstring, 3): the lags it
    leaves open would be any value, so it is no plant the log allows; its profiles hold each of them at a
    plausible value."""
    if plant.dropped or not (reason := plant.fitted.degenerate):
        return plant
    return dataclasses.replace(plant, dropped=f"degenerate: {reason}")


def allowed_plants(log: Log, log_name: str, options: LogFitOptions | None = None,
                   on_step: Callable[[str, int], Callable[[], None]] | None = None) -> Allowed:
    """The plants the log allows (module docstring). ``on_step(what, count)`` returns a callable that is
    called once per finished task of that step (a progress bar). NotFittable or ValueError where the log
    cannot be fitted at all; where no structure fits, no members (``Allowed.why_none`` says why)."""
    options = options or LogFitOptions()
    first = fit_log(log, options)  # the default fit: the heater, the segment, what kind of evidence
    base = dataclasses.replace(options, heater=first.heater, target_c=options.target_c or first.result.anchor_c)
    tasks = [_Task(_label(m, loss), dataclasses.replace(base, model=m, loss=loss), 0)
             for m, loss in structures(log, first)]
    fits = forked_map(_fit(log), tasks, on_done=_step(on_step, "fitting the structures", len(tasks)))
    judged = _judged(tasks, fits, [])
    dropped = [AllowedPlant(t.label, first, math.inf, dropped=f"does not fit: {f}", held=t.held)
               for t, f in zip(tasks, fits) if isinstance(f, str)]
    kept = [(t, p) for t, p in zip(tasks, judged) if p is not None and p.dropped is None]
    dropped += [p for p in judged if p is not None and p.dropped]
    if not kept:
        return Allowed(log_name, first.heater, first, [], dropped)
    best = min((p for _, p in kept), key=lambda p: p.delta).result
    ends = [_End(t, p.result, name, value, end) for t, p in kept for name, value, end in profile_points(p.result)]
    profiled = [degenerate(p) for p in _profiles(log, ends, best, on_step)]
    structures_kept = [degenerate(p) for _, p in kept]
    dropped += [p for p in structures_kept + profiled if p.dropped]
    candidates = [p for p in structures_kept + profiled if p.dropped is None]
    info = heater_settings(log, first.heater)
    replays = forked_map(lambda p: replay(log, p.fitted, info), candidates,
                         on_done=_step(on_step, "replaying the log on each plant", len(candidates)))
    replaying: list[AllowedPlant] = []
    for plant, r in sorted(zip(candidates, replays), key=lambda pr: pr[0].delta):
        plant = dataclasses.replace(plant, replay=r)
        if not r.passed:
            dropped.append(dataclasses.replace(plant, dropped=f"does not replay the log: {r.text()}"))
        else:
            replaying.append(plant)
    found, replaying, missed = calibration_check(log, first.heater, info, replaying, on_step, base)
    dropped += missed
    members: list[AllowedPlant] = []
    for plant in replaying:
        if (twin := _alike(plant, members)) is not None:
            dropped.append(dataclasses.replace(plant, dropped=f"alike {twin.label} (FOPDT equivalents within "
                                                              f"{ALIKE_REL:.0%})"))
        else:
            members.append(plant)
    return Allowed(log_name, first.heater, first, members, dropped, found)


def calibration_check(log: Log, heater: str, info: compare.HeaterInfo | None, plants: list[AllowedPlant],
                      on_step: Callable[[str, int], Callable[[], None]] | None = None,
                      options: LogFitOptions | None = None) -> tuple[str, list[AllowedPlant], list[AllowedPlant]]:
    """The plants against the printer's PID_CALIBRATE (module docstring, 5): what was found, the plants that
    reproduce it (each with its check) and those dropped with the reason; "" and the plants as they are for a
    log that is no klippy.log. Where some miss and ``options`` are given, their structures are refitted to
    relay at the saved period (tools/tuning/relay_refit.py) and judged as the others."""
    if not isinstance(log, StatsLog) or info is None:
        return "", plants, []
    saved, found = from_config(log.meta["config"].get(heater, {}))
    if saved is None or not plants:
        return f"{found}; not checked" if saved is None else f"{found}; no plant to check", plants, []
    checks = forked_map(lambda p: relay_evidence.check(p.result, info, heater, saved), plants,
                        on_done=_step(on_step, "replaying the log on each plant: your PID_CALIBRATE", len(plants)))
    kept = [dataclasses.replace(p, calibration=c) for p, c in zip(plants, checks) if c.passed]
    missed = [dataclasses.replace(p, calibration=c, dropped=f"does not reproduce your PID_CALIBRATE: {c.text()}")
              for p, c in zip(plants, checks) if not c.passed]
    line = f"{found}; {len(kept)} of {len(plants)} plants that replay the log reproduce it"
    if missed and options is not None:
        refits = _refits(log, options, info, saved, [p for p in plants if not p.held], on_step)
        kept += [p for p in refits if p.dropped is None]
        missed += [p for p in refits if p.dropped is not None]
        line += (f"; refitted to relay at its period: {sum(p.dropped is None for p in refits)} of {len(refits)} "
                 "structures replay the log and reproduce it")
    return line, kept, missed


def _refits(log: Log, options: LogFitOptions, info: compare.HeaterInfo, saved: SavedCalibration,
            structures: list[AllowedPlant], on_step: Callable[[str, int], Callable[[], None]] | None
            ) -> list[AllowedPlant]:
    """Each structure refitted to relay at the saved period, replayed and checked; a dropped one says why."""
    def run(plant: AllowedPlant) -> AllowedPlant:
        got = relay_refit.refit(log, options, plant.fitted, info, saved)
        if isinstance(got, str):
            return AllowedPlant(f"{plant.label}: refit", plant.fitted, math.inf, dropped=f"no refit: {got}", held=1)
        label, fitted = got
        r = replay(log, fitted, info)
        check = relay_evidence.check(fitted.result, info, fitted.heater, saved)
        why = None if r.passed and check.passed else \
            f"does not replay the log: {r.text()}" if not r.passed else \
            f"does not reproduce your PID_CALIBRATE: {check.text()}"
        return AllowedPlant(label, fitted, math.inf, r, why, 1, check)

    return forked_map(run, structures, on_done=_step(on_step, "replaying the log on each plant: refits",
                                                       len(structures)))


def no_relay_reason(checks: list[RelayCheck]) -> str:
    """Why no plant is a member where plants replayed the log but none reproduced the printer's PID_CALIBRATE:
    the saved Tu against the range the plants relay at over the band, and where some relay at the saved
    period (a refit), their Ku against the saved one."""
    saved = checks[0].saved
    band = "..".join(f"{t:g}" for t in checks[0].band_c)
    tus = [t for c in checks for t in c.tu_s if math.isfinite(t)]
    span = f"their own relay at {band} C at {min(tus):.3g}..{max(tus):.3g} s" if tus else \
        f"none of them finishes a PID_CALIBRATE at {band} C"
    on_period = [k * PID_PARAM_BASE for c in checks if c.tu_ok for k in c.ku if math.isfinite(k)]
    kus = (f"; those at its period relay at Ku {min(on_period):.3g}..{max(on_period):.3g} against its "
           f"{saved.ku * PID_PARAM_BASE:.3g}") if on_period else ""
    head = f"at the {saved.tu_s:.3g} s" if not on_period else \
        f"as your PID_CALIBRATE did (Tu {saved.tu_s:.3g} s, Ku {saved.ku * PID_PARAM_BASE:.3g})"
    return (f"no fitted plant relays {head}{' your PID_CALIBRATE saw' if not on_period else ''}: {len(checks)} "
            f"plants checked, {span}{kus} (goal: Tu within {relay_evidence.TU_GOAL_REL:.0%}, "
            f"Ku within {relay_evidence.KU_GOAL_REL:.0%})")


def _profiles(log: Log, ends: list[_End], best: FitResult,
              on_step: Callable[[str, int], Callable[[], None]] | None) -> list[AllowedPlant]:
    """Each end refitted and judged against the best fit; an end the evidence excludes once more halfway."""
    def run(tasks: list[_Task]) -> list[AllowedPlant | None]:
        fits = forked_map(_fit(log), tasks, on_done=_step(on_step, "profiling what the log leaves open", len(tasks)))
        return _judged(tasks, fits, [best])

    at_ends = run([e.task(e.end) for e in ends])
    again = [e for e, p in zip(ends, at_ends) if p is None or p.dropped]
    halfway_there = run([e.task(halfway(e.name, e.value, e.end)) for e in again]) if again else []
    return [p for p in at_ends + halfway_there if p is not None]


def _alike(plant: AllowedPlant, members: list[AllowedPlant]) -> AllowedPlant | None:
    mine = np.array(fopdt_equivalent(plant.result))
    for member in members:
        theirs = np.array(fopdt_equivalent(member.result))
        if np.all(np.abs(mine - theirs) <= ALIKE_REL * np.abs(theirs)) and abs(plant.ambient_c - member.ambient_c) < 1:
            return member
    return None


def heater_settings(log: Log, heater: str) -> compare.HeaterInfo | None:
    """A klippy.log heater's settings (sensor, max_power, gains, ...), None for other logs or a heater without PID."""
    if not isinstance(log, StatsLog):
        return None
    try:
        return compare.heater_info(log, heater)
    except compare.Unusable:
        return None


def _step(on_step: Callable[[str, int], Callable[[], None]] | None, what: str, count: int
          ) -> Callable[[], None] | None:
    return None if on_step is None else on_step(what, count)


__all__ = ["Allowed", "AllowedPlant", "Replay", "allowed_plants", "evidence"]
