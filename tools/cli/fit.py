"""twin-fit: fit a thermal model to a heater log; print its parameters, what the log cannot tell, every
plant it allows, and the gains twin-tune's tuner would print.

LOG is any log tools/logs/ reads: Klipper Stats CSV or klippy.log, a Klipper heattest, a plain
t,temp,duty CSV (one segment fitted: --segment, default the first with at least half the longest
time at full power); Marlin M303 console text, with or without its 2 s status trace (the printed
relay cycles, each a measured point of the loop, fitted with the trace where there is one) and with or
without its M303 command (the heater and the relay's target are then found in the data and said:
tools/logs/m303.py, tools/ident/relay_trace.py); Klipper PID_CALIBRATE results (one entry's Tu and
swing). tools/ident/log_fit.py does the fitting. The output gives each parameter with its standard error
and whether the log identifies it, a plausible range with its source for those it does not, the
residuals; then every plant the log allows (tools/tuning/allowed.py: the structures that fit about as
well, each open parameter profiled, each plant replaying the log's own numbers) and those it does not;
a FOPDT equivalent, Marlin's M306 for two_node; and twin-tune's answer, the very lines `twin-tune --from-log
LOG` prints (tools/tuning/answer.py: its default tune, proven on every plant the log allows against the
printer's own gains: new gains only where they beat them, else "keep your gains" and why, with the
closest candidate as an option), at the relay's target for relay data, else the log's. A fit that
identifies none of its model's lags is reported and is no plant the log allows (its profiles may be).
``--fit-only``: the fit alone, no gains. --loss radiating or auto adds a radiation-like loss to
two_node/three_node (docs/plants.md); an M303 capture whose status trace and relay target span less than
100 C cannot tell it from a linear loss, and says so (exit 2).

Exit status: as twin-tune's (below); with --fit-only, 3 where the fit is degenerate.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Callable
from typing import TYPE_CHECKING
from pathlib import Path

import numpy as np

from tools.cli.args import ranged_float
from tools.entry import OneLineParser, run_main
from tools.cli.progress import load_with_progress, progress_bar
from tools.ident.fit import LOSSES, LUMPED_MODELS, MODELS, RADIATING_BOUNDS_M2, RADIATING_EMISSIVITY, RADIATING_PARAM
from tools.ident.fopdt import CONTROL_DELAY_S, Fopdt, fopdt_equivalent, relay_fopdt, ultimate_point
from tools.ident.log_fit import BED, HEATER_NAMES, LogFit, LogFitOptions, fit_log
from tools.ident.lsq import MAX_EVALUATIONS
from tools.ident.relay_points import CYCLE_SCATTER_SWING_REL, CYCLE_SCATTER_TU_REL, RelayPoint
from tools.ident.relay_trace import AMBIENT_PRIOR_C
from tools.ident.result import FitResult
from tools.ident.segments import NotFittable
from tools.logs import MARLIN_POWER_MAX, Log, LogError, M303Log, StatsLog
from tools.progress import Steps
from tools.tuning.defaults import DEFAULT_BUDGET, EXIT_ANSWER, EXIT_CODES, EXIT_NO_MODEL, PROOF_SEEDS
from twin.limits import AMBIENT_RANGE_C, UserError
from twin.plants import BED_POWER_W, MPC_HEATER_POWER_W

if TYPE_CHECKING:  # the tuning layer (numba, scipy) is imported where gains are computed, not at start-up
    from tools.tuning.allowed import Allowed

WIDTH = 120  # output lines are wrapped to this
MARLIN_KU_SCALE = 255.0  # M303 prints Ku = 4 d / (pi a) with the relay's half swing d on 0..255
STATS_NOTE = ("Klipper Stats: pwm is the last value sent to the MCU, once a second; Klipper holds back a change "
              "under 5 % of max_power for up to 2.1..3.75 s (by version). It is the input all the same.")
ERRORS_NOTE = ("standard errors: from the Jacobian, for independent residuals; a log's residuals are correlated "
               "(model error, quantised readings), so take them as lower bounds")

EXAMPLES = """examples:
  twin-fit klippy.log                                   the extruder's heat-up, two_node (gives M306)
  twin-fit klippy.log --heater heater_bed --power-w 250 the bed, with its real wattage
  twin-fit heattest.csv --model three_node --ambient 21.4
  twin-fit m303_capture.txt --ambient 24                an M303 console capture (printed cycles, status trace)
  twin-fit m303_results.txt                             the M303 result lines alone: fopdt from the cycles
  twin-fit m303_capture.txt --fit-cycles 2              the first two printed cycles only
  twin-fit pasted_m303.txt                              bias/Ku/Tu lines without their M303 line: the heater
                                                        and the target found in the data
  twin-fit m303_bed.txt --heater heater_bed             where the data would say otherwise
  twin-fit pid_results.txt --segment 3                  a PID_CALIBRATE result: Tu and swing, gain held
  twin-fit heattest.csv --model three_node --loss auto  with a radiation-like loss too, if AIC prefers it
"""
BUDGET_MAX = 1_000_000  # as twin-tune's
PROOF_MAX = 10_000  # as twin-tune's
POWER_RANGE_W = (0.1, 5000.0)  # a 0.1 W test heater to a mains bed
TARGET_RANGE_C = (1.0, 500.0)  # a relay target: above freezing, below any hotend's limit


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="twin-fit", description=__doc__, epilog=EXAMPLES + EXIT_CODES)
    parser.add_argument("log", metavar="LOG", help="the log file")
    parser.add_argument("--model", choices=MODELS,
                        help="two_node (Marlin's MPC model, gives M306; the default for a trace), three_node (plus "
                             "the heater cartridge: the default for an M303 capture with a status trace), fopdt (the "
                             "default for relay results alone) or sopdt (first/second order plus dead time)")
    parser.add_argument("--heater", choices=HEATER_NAMES,
                        help="extruder or heater_bed (default: extruder, or the log's only heater; for an M303 "
                             "capture, the heater its M303 command or its lines say, else the one its relay's "
                             "target says: above Marlin's highest bed target, 140 C, a hotend)")
    parser.add_argument("--session", type=int, help="only this session of a Klipper log (0-based, as listed)")
    parser.add_argument("--segment", type=int, help="the segment to fit (as listed; default: the first with at "
                        "least half the longest time at full power); for PID_CALIBRATE results, the entry (default 0)")
    parser.add_argument("--fit-cycles", type=int, metavar="K",
                        help="an M303 capture: fit the first K printed cycles only (and the trace up to them)")
    parser.add_argument("--target", type=ranged_float(*TARGET_RANGE_C, "C"),
                        help="relay data: the relay's target in C where the capture does not state it (default: an "
                             "M303 capture's command, else the whole degree within every printed cycle's min..max "
                             "nearest its status trace's switches or that range's middle; PID_CALIBRATE results: "
                             "200 C for a hotend, 60 C for a bed, assumed); the suggested gains are tuned there")
    parser.add_argument("--ambient", type=ranged_float(*AMBIENT_RANGE_C, "C"),
                        help="ambient temperature in C (default: fitted, at most the segment's lowest reading; for "
                             "relay data, whose readings all sit near the target, the idle bed's reading or "
                             f"{AMBIENT_PRIOR_C:g} C)")
    parser.add_argument("--power-w", type=ranged_float(*POWER_RANGE_W, "W"),
                        help="heater power in W for two_node/three_node (default: assumed "
                        f"{MPC_HEATER_POWER_W:g} W for a hotend, {BED_POWER_W:g} W for a bed)")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET,
                        help=f"the tune's optimiser evaluations, as twin-tune's --budget (default: {DEFAULT_BUDGET})")
    parser.add_argument("--proof", type=int, default=PROOF_SEEDS, metavar="SEEDS",
                        help=f"noise seeds of the proof on every plant, as twin-tune's --proof "
                             f"(default: {PROOF_SEEDS})")
    parser.add_argument("--fit-only", action="store_true",
                        help="the fit alone: no other structures, profiles or replays, no gains (fast)")
    parser.add_argument("--loss", choices=LOSSES, default="linear",
                        help="two_node/three_node heat loss: linear (the default, Marlin's MPC model), radiating "
                             "(plus sigma area (T^4 - Ta^4), an effective area at emissivity 1 fitted within "
                             f"{RADIATING_BOUNDS_M2[0] * 1e4:g}..{RADIATING_BOUNDS_M2[1] * 1e4:g} cm^2) or auto "
                             "(both, the lower AIC kept); an M303 capture: where its status trace and relay target "
                             "span 100 C or more (its relay cycles on the plant linearised at the target), else "
                             "refused")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.loss != "linear" and args.model not in (None, *LUMPED_MODELS):
        parser.error(f"--loss {args.loss} needs --model two_node or three_node: {args.model} has no heat-loss term")
    if args.fit_cycles is not None and args.fit_cycles < 1:
        parser.error(f"argument --fit-cycles: {args.fit_cycles}: at least one cycle")
    if not 1 <= args.budget <= BUDGET_MAX:
        parser.error(f"argument --budget: {args.budget}: must be within 1 .. {BUDGET_MAX}")
    if not 1 <= args.proof <= PROOF_MAX:
        parser.error(f"argument --proof: {args.proof}: must be within 1 .. {PROOF_MAX} seeds")
    return args


# --- the report, step by step --------------------------------------------------------------------


def _wrap(text: str, indent: str = "  ") -> list[str]:
    return textwrap.wrap(text, WIDTH, initial_indent=indent, subsequent_indent=indent + "  ")


def _wrap_keeping_indent(line: str) -> list[str]:
    indent = line[: len(line) - len(line.lstrip())]
    return _wrap(line.lstrip(), indent) if len(line) > WIDTH else [line]


def _log_lines(log: Log, fitted: LogFit) -> list[str]:
    """What the log is and the segments it offers, the fitted one starred."""
    lines = [f"{log.format}; heater {fitted.heater}"]
    if fitted.segments:
        lines[0] += "; segments (open loop: full power or off; in between: the controller's duty):"
        for i, seg in enumerate(fitted.segments):
            seg = fitted.segment if i == fitted.chosen and fitted.segment is not None else seg
            lines.append(f"  {'*' if i == fitted.chosen else ' '}{i:3d}  {seg.label}, {len(seg.t_s)} samples:")
            lines += _wrap(seg.note, " " * 8)
    return lines


def _point_lines(points: list[RelayPoint]) -> list[str]:
    """The relay cycles fitted: their levels, what they printed, what the bias steps bracket."""
    if not points:
        return []
    lines = ["relay cycles fitted (levels in duty 0..1; t_high - t_low from the bias update, where there is one):"]
    for p in points:
        extremes = f"min {p.min_c:.2f} max {p.max_c:.2f}" if p.min_c is not None else f"swing {p.swing_c:.2f} C"
        asym = f", t_high - t_low {p.asymmetry_s[0]:+.2f}..{p.asymmetry_s[1]:+.2f} s" if p.asymmetry_s else ""
        lines += _wrap(f"line {p.line_no}: target {p.relay.target_c:g} C, on {p.relay.on_duty:.3f} off "
                       f"{p.relay.off_duty:.3f}: Tu {p.tu_s:.2f} s, {extremes}{asym}"
                       + (f" ({p.levels_note})" if p.levels_note else ""))
    return lines


def _residual_lines(result: FitResult, fitted: LogFit) -> list[str]:
    if result.evidence == "trace":
        return [f"  RMSE {result.rmse_c:.2f} C, max |residual| {result.max_abs_residual_c:.2f} C"
                f" over {result.n_samples} samples"]
    what = "relay cycles and trace" if "trace" in result.evidence else "relay cycles"
    lines = [f"  {what}: RMS residual {result.rmse_c:.2f} in units of the cycles' scatter (Tu "
             f"{100 * CYCLE_SCATTER_TU_REL:g} %, swing {100 * CYCLE_SCATTER_SWING_REL:g} %)"]
    trace = fitted.trace_residuals_c()
    if trace.size:
        lines.append(f"  trace: RMSE {float(np.sqrt(np.mean(trace ** 2))):.2f} C, max |residual| "
                     f"{float(np.max(np.abs(trace))):.2f} C over {trace.size} readings")
    return lines


def _spread_lines(result: FitResult) -> list[str]:
    """What the data cannot tell: each parameter left open, its range and where the range comes from."""
    spread = result.spread()
    if not spread:
        return ["what the data cannot tell: nothing among the fitted parameters (all identified)"]
    lines = ["what the data cannot tell (tools/ident/plausible.py; FitResult.spread() gives these to a tuner):"]
    for r in spread:
        lines += _wrap(f"{r.name} {r.low:.4g}..{r.high:.4g}: {r.source}")
    return lines


def _settings_lines(result: FitResult, heater: str, sample_s: float) -> list[str]:
    """The FOPDT equivalent and its ultimate point (on a dead time of at least the log's sample interval: a
    log cannot show a shorter one); the M306 line of a two-node fit."""
    fopdt = fopdt_equivalent(result)
    how = "the fit itself" if result.model == "fopdt" else "seed 001's two-point method on the model's step response"
    lines = [f"FOPDT equivalent ({how}): gain {fopdt.gain_c:.4g} C at full power, time constant "
             f"{fopdt.time_constant_s:.4g} s, dead time {fopdt.delay_s:.3g} s"]
    if fopdt.delay_s < sample_s:
        fopdt = fopdt._replace(delay_s=sample_s)
        lines.append(f"  on a dead time of {sample_s:.3g} s, the log's sample interval: it cannot show less")
    delayed = fopdt._replace(delay_s=fopdt.delay_s + CONTROL_DELAY_S)
    ku, tu_s = ultimate_point(delayed)
    lines += [f"  with the loop's {CONTROL_DELAY_S:g} s of delay: ultimate gain Ku {ku:.4g} duty per C ({ku * 255:.4g} "
              f"in Marlin's M303 units), period Tu {tu_s:.4g} s: what an ideal relay test would find, not a tune"]
    if heater != BED:
        lines += ["MPC (the fitted model's own constants; `twin-tune --from-log LOG --controller mpc` proves a tune):",
                  *_mpc_lines(result)]
    return lines


def _mpc_lines(result: FitResult) -> list[str]:
    """Marlin's M306 line where the model is Marlin's MPC model, else why not."""
    v = result.values
    if result.model == "two_node" and result.loss == "radiating":
        return ["  Marlin:  (M306 has no radiation term: --loss linear fits Marlin's MPC model)"]
    if result.model != "two_node":
        return ["  Marlin:  (M306 needs --model two_node: Marlin's MPC is that two-node model)"]
    return [f"  Marlin:  M306 P{v['power_w']:.2f} C{v['block_heat_capacity_j_k']:.2f} "
            f"R{v['sensor_responsiveness_per_s']:.4f} A{v['ambient_xfer_w_k']:.4f} F{v['ambient_xfer_w_k']:.4f}",
            "           (P as assumed: with your heater's P', scale C, A and F by P'/P; F = A, the log "
            "has no part-fan speed)"]


def _radiation_line(result: FitResult) -> str:
    """The fitted radiating area in cm^2 with its standard error, and what it stands for."""
    area_cm2 = result.params[RADIATING_PARAM] * 1e4
    error = result.std_errors[RADIATING_PARAM] * 1e4
    spread = "at its bound" if np.isnan(error) else "not determined" if np.isinf(error) else f"+- {error:.2g} cm^2"
    return (f"  radiation: effective area {area_cm2:.4g} cm^2 {spread}, at emissivity {RADIATING_EMISSIVITY:g} "
            "(stands for every loss that grows faster than linearly with temperature)")


def _fit_report(fitted: LogFit, log: Log) -> list[str]:
    """Everything about the fit itself, before the settings."""
    result = fitted.result
    on = "segment" if fitted.chosen is not None else "the printed cycles"
    where = f" on {on} {fitted.chosen}" if fitted.chosen is not None else f" on {on}"
    lines = [f"loss (--loss auto): {'; '.join(fitted.compared)}: kept {result.loss} (lower AIC)"] if fitted.compared \
        else []
    lines += [f"fit: {result.model}{', radiating loss' if result.loss == 'radiating' else ''}{where} ({result.evidence})"]
    lines += [f"  {note}" for note in fitted.notes]
    lines += result.parameter_lines() + ([_radiation_line(result)] if result.loss == "radiating" else [])
    lines += _residual_lines(result, fitted)
    if derived := result.derived():
        lines.append("  power-free: " + ", ".join(f"{name} {value:.4g}" for name, value in derived.items()))
    lines += _wrap(ERRORS_NOTE)
    if isinstance(log, StatsLog):
        lines.append(STATS_NOTE)
    return lines + _spread_lines(result)


def _log_notes(log: Log, fitted: LogFit) -> list[str]:
    """The log's own gains or relay result next to the fit, where it has them."""
    if isinstance(log, StatsLog) and (config := log.meta["config"].get(fitted.heater, {})).get("pid_kp"):
        return [f"the log's own gains: pid_Kp {config['pid_kp']}, pid_Ki {config.get('pid_ki')}, "
                f"pid_Kd {config.get('pid_kd')}"]
    if not isinstance(log, M303Log) or log.power_max != MARLIN_POWER_MAX:  # Repetier's Ku takes the full swing
        return []
    cycle = next((c for c in reversed(log.cycles) if c.ku and c.tu_s), None)
    if cycle is None or cycle.ku is None or cycle.tu_s is None:
        return []
    return [_relay_line(cycle.ku / MARLIN_KU_SCALE, cycle.tu_s, fopdt_equivalent(fitted.result))]


def _relay_line(ku: float, tu_s: float, fitted: Fopdt) -> str:
    """The log's own relay result as a FOPDT through the fitted gain, next to the fitted FOPDT."""
    try:
        relay = relay_fopdt(ku, tu_s, fitted.gain_c)
    except ValueError as exc:
        return f"the log's last relay cycle, Ku {ku:.4g} Tu {tu_s:.4g} s: {exc}"
    return (f"the log's last relay cycle, Ku {ku:.4g} duty per C, Tu {tu_s:.4g} s, through the fitted gain: time "
            f"constant {relay.time_constant_s:.4g} s, dead time {relay.delay_s:.3g} s (relay_fopdt; the fit: "
            f"{fitted.time_constant_s:.4g} s, {fitted.delay_s:.3g} s)")


def _options(args: argparse.Namespace, on_evaluation) -> LogFitOptions:
    return LogFitOptions(args.model, args.heater, args.session, args.segment, args.ambient, args.power_w, args.loss,
                         args.fit_cycles, args.target, on_evaluation=on_evaluation)


def run(args: argparse.Namespace) -> int:
    log = load_with_progress(args.log)
    name = Path(args.log).name
    if args.fit_only:
        with progress_bar("fitting", MAX_EVALUATIONS, "evaluations") as bar:
            fitted = fit_log(log, _options(args, bar.update))
        allowed = None
    else:
        from tools.tuning.allowed import allowed_plants

        allowed = allowed_plants(log, name, _options(args, None), Steps("bar"))
        fitted = allowed.first  # the fit the options ask for; the plants the log allows follow it
    print(f"twin-fit: {args.log}")
    lines = _log_lines(log, fitted) + _point_lines(fitted.points) + _fit_report(fitted, log)
    print("\n".join(lines + ([] if allowed is None else allowed.lines())))
    reason = fitted.degenerate
    if allowed is None:
        if reason:
            print(f"twin-fit: {args.log}: degenerate fit, no settings: {reason}", file=sys.stderr)
            return EXIT_NO_MODEL
        _print_wrapped(_settings_lines(fitted.result, fitted.heater, fitted.resolution_s) + _log_notes(log, fitted)
                       + ["gains: not with --fit-only (twin-fit without it prints twin-tune's answer)"])
        return EXIT_ANSWER
    return _answer(args, log, allowed, reason)


def _answer(args: argparse.Namespace, log: Log, allowed: Allowed, reason: str | None) -> int:
    """The settings of the fit the options ask for (of the best plant the log allows where that fit is
    degenerate) and twin-tune's answer (tools/tuning/answer.py)."""
    fitted = allowed.best if reason else allowed.first  # the fit the options ask for, unless it is degenerate
    settings = [f"the {allowed.first.result.model} fit is degenerate ({reason}): no plant the log allows; the "
                f"settings below are the best member's, {fitted.result.model}"] if reason and allowed.members else []
    if not reason or allowed.members:
        settings += _settings_lines(fitted.result, fitted.heater, fitted.resolution_s) + _log_notes(log, fitted)
    from tools.tuning.answer import default_tune, no_model_lines, verdict_lines
    from tools.tuning.problems import NoModel, allowed_source, build_problem

    try:
        source = allowed_source(log, allowed, _options(args, None))
    except NoModel as exc:
        status, verdict = no_model_lines(exc, exc.printer)
        _print_wrapped(settings)
        print("\n".join(verdict))  # as twin-tune prints them
        if status == EXIT_NO_MODEL:
            print(f"twin-fit: {exc}", file=sys.stderr)
        return status
    problem = build_problem(source, args.target)
    _, proof = default_tune(problem, source.printer, args.budget, args.proof, Steps("bar"))
    status, verdict = verdict_lines(problem, proof, source.is_bed, source.printer)
    _print_wrapped(settings)
    print("\n".join(verdict))  # as twin-tune prints them
    return status


def _print_wrapped(lines: list[str]) -> None:
    """The lines on stdout, each wrapped to WIDTH with its indent kept."""
    print("\n".join(wrapped for line in lines for wrapped in _wrap_keeping_indent(line)))


def _describe(log: str) -> Callable[[BaseException], str]:
    """The one-line error for a log that cannot be read or fitted."""
    def describe(exc: BaseException) -> str:
        if isinstance(exc, LogError):
            return str(exc)
        return f"{log}: not usable for fitting: {exc}" if isinstance(exc, NotFittable) else f"{log}: {exc}"

    return describe


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return run_main("twin-fit", lambda: run(args), errors=(LogError, NotFittable, UserError),
                    describe=_describe(args.log))


if __name__ == "__main__":
    raise SystemExit(main())
