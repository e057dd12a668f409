"""twin-tune: tune a heater controller on the firmware in the loop; new gains only where they beat yours.

The plant is a preset (``--plant``) or a log (``--from-log``: every plant the log allows, fitted,
profiled and replayed against the log: tools/tuning/allowed.py); the controller is a firmware build
with parameters (``--controller``, default Marlin's fixed-point PID) or your own ``module:attribute``
naming a firmware_port.params.ParamSpace. The gains to beat are yours: the printer's own, from the log
or ``--current-gains``, else the firmware's own autotune on the twin. Every candidate (the tuning rules
for a PID, an optimiser's search) runs the same scenario in the loop (tools/tuning/evaluate.py:
heat-up, then disturbances) on every plant of the ensemble with ADC noise, scored by the objective
(tools/tuning/objectives.py, charged where it is worse than yours) and reduced to a robust statistic.
The best candidates and yours are then proven on every plant over many noise seeds on the batch, a
sample cross-checked on the reference engine (tools/tuning/proof.py); the answer is new gains only
where one beats yours on every plant (tools/tuning/verdict.py), else "keep your gains".
Every candidate follows beside the references, and a plot of the responses is written.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from tools.cli.args import check_output, finite_float, output_file, plot_path
from tools.progress import PROGRESS_MODES, Steps
from twin.limits import NOISE_MAX_LSB, SEED_MAX, UserError
from tools.entry import OneLineParser, run_main
from tools.tuning.controllers import controller_names
from tools.ident.log_fit import LogFitOptions
from tools.ident.segments import NotFittable
from tools.logs import LogError
from tools.tuning.ensemble import DEFAULT_NOISE_LSB, DEFAULT_SPREAD, DEFAULT_STATISTIC, STATISTICS
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX
from firmware_port.firmwares import KALICO_MPC
from tools.tuning.evaluate import LOOPS, Candidate, Problem
from tools.tuning.answer import CANNOT_MODEL, no_model_lines, settings_lines, verdict_lines
from tools.tuning.exits import EXIT_ANSWER, EXIT_CODES, EXIT_NO_MODEL
from tools.tuning.gains import Gains
from tools.tuning.verdict import KEEP
from tools.tuning.problems import (
    BED_TARGET_C,
    HOTEND_TARGET_C,
    NoModel,
    Source,
    build_problem,
    log_source,
    preset_source,
)
from tools.tuning.objectives import DEFAULT_OBJECTIVE, OBJECTIVES, heater_terms
from tools.tuning.proof import CROSS_CHECK_S, PROOF_SEEDS, ProofRow
from tools.tuning.reference import PrinterGains, parse_gains
from tools.tuning.proof import table as proof_table
from tools.tuning.tuner import DEFAULT_BUDGET, Proven, TuneResult, methods, proven, tune
from twin.metrics import step_metrics
from twin.plants import SPECS

BOTH = "both"  # --loop both: tune and prove on Marlin's loop, then on Klipper's
BUDGET_MAX = 1_000_000  # optimiser evaluations: a thousand times the default, days of CPU
PROOF_MAX = 10_000  # noise seeds in the proof
MODELS = ("two_node", "three_node", "fopdt", "sopdt")
EPILOG = """examples:
  twin-tune --plant hotend_cartridge --target 210            # rules, then DE, against M303 C8
  twin-tune --plant hotend_cartridge --method ocalo --budget 900 --seed 1
  twin-tune --controller fuzzy_pi --plant bed --target 60    # seed 004's fuzzy PI: its three ranges
  twin-tune --controller my_module:SPACE --plant hotend      # your own controller (a ParamSpace)
  twin-tune --controller pid,mpc --plant hotend_cartridge --budget 100   # PID against Marlin's MPC
  twin-tune --from-log klippy.log --heater extruder --loop klipper
  twin-tune --plant hotend --loop kalico                      # Kalico's PID, against its PID_CALIBRATE
  twin-tune --controller pid,mpc --plant hotend --loop kalico # Kalico's PID against its MPC (MPC_CALIBRATE)

  twin-tune --from-log m303.txt --current-gains "M301 P22.2 I1.08 D114" --json answer.json

""" + EXIT_CODES
AUTO = "auto"  # --loop auto: the loop the log's printer runs (Marlin for a preset)


# -- the plant ---------------------------------------------------------------------------------
def source(args: argparse.Namespace, steps: Steps) -> Source:
    """The plant: a preset, or every plant the log allows (tools/tuning/allowed.py)."""
    if not args.from_log:
        return preset_source(args.plant, args.spread)
    options = LogFitOptions(model=args.model, heater=args.heater, segment=args.segment, target_c=args.target)
    return log_source(args.from_log, options, on_step=steps, ensemble=args.spread > 0)


def make_problem(args: argparse.Namespace, plant: Source, loop: str, controller_name: str) -> tuple[Problem, bool]:
    """The problem the arguments describe on ``plant`` (with ``loop`` and ``controller_name``), and whether its
    heater is a bed. On the kalico loop ``mpc`` is Kalico's MPC."""
    if loop == "kalico" and controller_name == "mpc":
        controller_name = KALICO_MPC
    problem = build_problem(plant, args.target, controller_name, None if loop == AUTO else loop, args.noise,
                            args.statistic, spread=args.spread > 0)
    return problem, plant.is_bed


def plant_lines(plant: Source) -> list[str]:
    """A log's plants: the best fit's parameters, exactly as twin-fit prints them, then every plant the log
    allows and the fits it does not."""
    if plant.fitted is None:
        return []
    result = (plant.allowed.first if plant.allowed is not None else plant.fitted).result
    lines = [f"plant: {result.model} fitted to {plant.name.split(' (')[0]} as twin-fit fits it:",
             *result.parameter_lines()]
    return lines + (plant.allowed.lines() if plant.allowed is not None else [])


def given_gains(args: argparse.Namespace) -> PrinterGains | None:
    """--current-gains, where given."""
    return PrinterGains(parse_gains(args.current_gains), "--current-gains") if args.current_gains else None


def yours(args: argparse.Namespace, plant: Source) -> PrinterGains | None:
    """The printer's gains: --current-gains, else what the log states."""
    return given_gains(args) or plant.printer


# -- output -------------------------------------------------------------------------------------
def metrics_line(candidate: Candidate) -> str:
    """Heat-up metrics (twin/metrics.py) and the heater objective's terms of one candidate."""
    run = candidate.run
    heat = run.t_s < run.heatup_end_s
    m = step_metrics(run.t_s[heat], run.temp_c[heat, 0], run.target_c, np.clip(run.duty[heat, 0], 0, 1))
    terms = heater_terms(run)

    def show(value: float | None, unit: str) -> str:
        return "-" if value is None else f"{value:.1f}{unit}"

    cycle = "" if m.limit_cycle_amplitude_c is None else \
        f", LIMIT CYCLE +-{m.limit_cycle_amplitude_c:.2f} C every {m.limit_cycle_period_s:.1f} s"
    return (f"rise {show(m.rise_time_s, ' s')}, overshoot {show(m.overshoot_c, ' C')}, settling(2%) "
            f"{show(m.settling_time_2pct_s, ' s')}, IAE {m.iae_c_s:.0f} C s, ITAE {m.itae_c_s2:.3g} C s^2, "
            f"hold |e| {terms.hold_error_c[0]:.2f} C" + cycle + (", PROTECTION TRIP" if terms.tripped[0] else ""))


def describe(problem: Problem, candidate: Candidate) -> str:
    """A candidate's parameters: gains for a PID family, else each parameter with its unit."""
    return str(candidate.gains) if problem.controller.pid else problem.controller.describe(candidate.params)


def report_proof(problem: Problem, proof: Proven, seeds: int) -> None:
    members = len(problem.members())
    print(f"proof on the batch: {seeds} noise seeds on each of the {members} plants, the candidates beside "
          f"{proof.yours.method}; cross-check: {proof.cross_check}:")

    def named(row: ProofRow) -> str:
        return problem.controller.describe(row.params) if not problem.controller.pid else \
            f"Kp {row.params[0]:.4g} Ki {row.params[1]:.4g} Kd {row.params[2]:.4g}"

    shown = {proof.verdict.shown, proof.yours.method}
    print("\n".join("  " + line for line in proof_table([r for r in proof.rows if r.method in shown], named)))
    for method, missed in proof.verdict.misses.items():
        if method not in shown and not missed:
            print(f"  also proven: {method}: beats {proof.yours.method} too; {proof.verdict.shown} holds as well and "
                  "overshoots less")
        elif method not in shown:
            member, why = next(iter(missed.items()))
            print(f"  also proven: {method}: misses on {member}: {'; '.join(why)}")


def report(result: TuneResult, proof: Proven | None, seeds: int, is_bed: bool, printer: PrinterGains | None) -> int:
    """Print the tune; the exit status (tools/tuning/answer.py)."""
    problem, best = result.problem, result.best
    print(f"twin-tune: {problem.name} at {problem.scenario.target_c:g} C, controller {problem.controller.name}, "
          f"objective {result.objective}, loop {problem.loop}")
    if problem.ensemble is not None:
        print(f"ensemble: {problem.ensemble.describe()}")
    if printer is not None:
        print(f"your gains: {printer.gains} ({printer.source})")
    print(f"to beat: {result.yours.method}  {describe(problem, result.yours)}  cost {result.yours.cost:.4g}")
    print(f"best of the search: {best.method}  {describe(problem, best)}  cost {best.cost:.4g}")
    status, answer = EXIT_ANSWER, None
    if proof is not None:
        report_proof(problem, proof, seeds)
        answer = proof.answer
        status, lines = verdict_lines(problem, proof, is_bed, printer)
        print("\n".join(lines))
    elif problem.loop != "ideal":
        print("not proven (--proof 0): nothing below has been proven; the best of the search, unproven:")
        print("\n".join(settings_lines(problem, best.params, is_bed, proven_=False)))
    else:
        print("\n".join(settings_lines(problem, best.params, is_bed, proven_=False)))
    print(f"candidates on the {problem.loop} loop (best first), then the references; cost = {_statistic(problem)}:")
    shown = result.candidates + result.references
    width = max(len(c.method) for c in shown)
    texts = [describe(problem, c) for c in shown]
    text_width = max(len(t) for t in texts)
    for c, text in zip(shown, texts):
        mark = "*" if c is answer else " "
        print(f" {mark}{c.method:{width}}  {text:{text_width}}  cost {c.cost:10.4g}  {metrics_line(c)}")
    return status


def _statistic(problem: Problem) -> str:
    if problem.ensemble is None:
        return "the objective"
    return f"the {problem.ensemble.statistic} over {problem.ensemble.size} members; metrics of the nominal member"


def write_plot(path: Path, result: TuneResult, title: str) -> None:
    """Responses of the best candidates and the references (nominal plant): the whole run, the hold
    zoomed to where they differ, the disturbances labelled; the convergence of any optimiser."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    candidates, events = result.candidates, result.problem.scenario.events
    shown = candidates[:4] + result.references
    searched = [c for c in candidates if c.history is not None]
    fig, axes = plt.subplots(2 + bool(searched), 1, figsize=(10, 8 + 3 * bool(searched)), squeeze=False)
    run0 = candidates[0].run
    hold = run0.t_s >= run0.heatup_end_s - 20.0
    for ax in axes[:2, 0]:
        for c in shown:
            ax.plot(c.run.t_s, c.run.temp_c[:, 0], lw=1.2 if c is candidates[0] else 0.8,
                    label=f"{c.method}: {describe(result.problem, c)} (cost {c.cost:.4g})")
        ax.axhline(run0.target_c, color="k", ls=":", lw=0.8)
        for event in events:
            ax.axvline(event.at_s, color="grey", ls="--", lw=0.6)
            ax.annotate(f"{event.kind} {event.value:g}", (event.at_s, 1.0), xycoords=("data", "axes fraction"),
                        xytext=(2, -10), textcoords="offset points", fontsize=7, color="grey")
        ax.set(xlabel="time (s)", ylabel="measured temperature (C)")
    axes[0, 0].set_title(title)
    axes[0, 0].legend(fontsize=7)
    deviation = max(float(np.max(np.abs(c.run.temp_c[hold, 0] - run0.target_c))) for c in shown)
    axes[1, 0].set(xlim=(float(run0.t_s[hold][0]), float(run0.t_s[-1])),
                   ylim=(run0.target_c - 1.1 * deviation, run0.target_c + 1.1 * deviation),
                   title="holding, from the first disturbance on (zoomed)")
    if searched:
        for c in searched:
            axes[2, 0].semilogy(c.history, label=c.method)
        axes[2, 0].set(xlabel="iteration", ylabel="best cost")
        axes[2, 0].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# -- the command ----------------------------------------------------------------------------------
def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="twin-tune", description=__doc__.split("\n\n")[0], epilog=EPILOG)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--plant", help=f"a plant preset: {', '.join(SPECS)}")
    source.add_argument("--from-log", metavar="LOG", help="fit a plant to this log (as twin-fit), then tune it")
    parser.add_argument("--target", type=finite_float, help=f"setpoint in C (default {HOTEND_TARGET_C:g}, a bed "
                        f"{BED_TARGET_C:g})")
    parser.add_argument("--controller", default="pid", metavar="NAME[,NAME]",
                        help=f"a firmware build with parameters ({', '.join(controller_names())}) or a "
                             "module:attribute naming your ParamSpace; several, comma-separated, are tuned on the "
                             "same plant and compared, e.g. pid,mpc (default: pid)")
    parser.add_argument("--loop", default=AUTO, choices=(AUTO,) + LOOPS + (BOTH,),
                        help="the loop the candidates run in: Marlin's board, Klipper's host PID, Kalico's (its PID, "
                             "or its MPC with --controller mpc), the papers' idealised continuous loop, or both "
                             "firmware loops (Marlin's and Klipper's), each with its own answer "
                             "(default: auto, the log's firmware: klipper for a klippy.log, a Klipper heattest or "
                             "a PID_CALIBRATE result, else marlin)")
    parser.add_argument("--current-gains", metavar="GAINS",
                        help="your printer's gains, the answer to beat: P,I,D, 'M301 P.. I.. D..' or "
                             "'pid_Kp=.. pid_Ki=.. pid_Kd=..' (default: what the log states, else the firmware's "
                             "own autotune on the twin)")
    parser.add_argument("--ideal", action="store_const", dest="loop", const="ideal", help="same as --loop ideal")
    parser.add_argument("--method", default="auto", metavar="METHOD",
                        help=f"one of: {', '.join(methods())}. 'all': every rule and optimiser; 'auto' (default): "
                             "every rule (a PID), then DE")
    parser.add_argument("--objective", default=DEFAULT_OBJECTIVE, metavar="NAME",
                        help=f"one of: {', '.join(OBJECTIVES)} (default: {DEFAULT_OBJECTIVE})")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET,
                        help=f"objective evaluations per optimiser (default: {DEFAULT_BUDGET})")
    parser.add_argument("--seed", type=int, default=0, help="optimiser random seed (default: 0)")
    parser.add_argument("--noise", type=finite_float, metavar="LSB",
                        help=f"ADC noise of every ensemble member, in LSB of the loop's ADC (default: a log's own "
                             f"reading noise where its trace shows it, else {DEFAULT_NOISE_LSB:g})")
    parser.add_argument("--spread", type=finite_float, default=DEFAULT_SPREAD, metavar="FRACTION",
                        help=f"a preset's lag and loss terms spread +-FRACTION: the ensemble's corner plants "
                             f"(default: {DEFAULT_SPREAD:g}; 0: the nominal plant only, and for a log its fit alone, "
                             "not every plant it allows)")
    parser.add_argument("--statistic", default=DEFAULT_STATISTIC, choices=STATISTICS,
                        help=f"how the members' costs reduce to one (default: {DEFAULT_STATISTIC})")
    parser.add_argument("--proof", type=int, default=PROOF_SEEDS, metavar="SEEDS",
                        help=f"prove the best candidates and yours on every plant over SEEDS noise seeds each "
                             f"(default: {PROOF_SEEDS}; 0: skip, and nothing is called proven)")
    parser.add_argument("--cross-check", type=finite_float, default=CROSS_CHECK_S, metavar="SECONDS",
                        help=f"re-run the first SECONDS of one proof run on the reference engine and stop if its "
                             f"readings differ from the batch's (default: {CROSS_CHECK_S}; 0: skip)")
    parser.add_argument("--json", metavar="FILE", type=output_file,
                        help="also write the answer as JSON (verdict, why, gains, commands, plants, proof rows)")
    parser.add_argument("--progress", default="bar", choices=PROGRESS_MODES,
                        help="progress on stderr: tqdm bars on a terminal (bar, the default) or one line per "
                             "step of work, 'progress: <step> <done>/<total>' (lines: for a program reading it)")
    parser.add_argument("--model", metavar="MODEL",
                        help=f"--from-log: the model to fit, one of {', '.join(MODELS)} (default: as twin-fit, "
                             "two_node for a trace, three_node for an M303 capture)")
    parser.add_argument("--heater", help="--from-log: extruder or heater_bed (default: the log's first)")
    parser.add_argument("--segment", type=int, help="--from-log: the segment to fit (default: the longest heat-up)")
    parser.add_argument("--plot", help="plot file (default twin-out/twin-tune-<plant>.png); 'none' for no plot")
    parser.add_argument("--dask", metavar="ADDRESS", help="a dask.distributed scheduler (tcp://host:port)")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def check_args(args: argparse.Namespace) -> None:
    if args.objective not in OBJECTIVES:
        raise UserError(f"--objective {args.objective!r}: choose one of: {', '.join(OBJECTIVES)}")
    if not 1 <= args.budget <= BUDGET_MAX:
        raise UserError(f"--budget {args.budget}: must be within 1 .. {BUDGET_MAX}")
    if args.noise is not None and not 0 <= args.noise <= NOISE_MAX_LSB:
        raise UserError(f"--noise {args.noise:g}: must be within 0 .. {NOISE_MAX_LSB:g} LSB")
    if not 0 <= args.spread < 1:
        raise UserError(f"--spread {args.spread:g}: must be within 0 .. 1 (a fraction)")
    if not 0 <= args.proof <= PROOF_MAX:
        raise UserError(f"--proof {args.proof}: must be within 0 .. {PROOF_MAX} seeds")
    if not 0 <= args.seed <= SEED_MAX:
        raise UserError(f"--seed {args.seed}: must be a whole number >= 0 (below 2**63)")
    if args.method not in methods():
        raise UserError(f"--method {args.method!r}: choose one of: {', '.join(methods())}")
    if args.model is not None and args.model not in MODELS:
        raise UserError(f"--model {args.model!r}: choose one of: {', '.join(MODELS)}")
    if args.cross_check < 0:
        raise UserError(f"--cross-check {args.cross_check:g}: must be >= 0 seconds (0: skip)")
    if args.current_gains:
        check_current_gains(args.current_gains)
    check_plot(args)


def check_plot(args: argparse.Namespace) -> None:
    """--plot (or the default one): a file we can write, in a format matplotlib writes."""
    path = plot_file(args)
    try:
        if path is not None and args.plot is None and not path.parent.exists():
            check_output(path.parent)  # the default folder, made at the end: it can be
        elif path is not None:
            plot_path(str(path))
    except (argparse.ArgumentTypeError, ValueError) as exc:
        raise UserError(f"--plot {path}: {exc}") from None


def check_current_gains(text: str) -> None:
    """--current-gains: gains parse_gains reads, each within what the firmware takes (Marlin's PID_MAX scale)."""
    try:
        gains = parse_gains(text)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    for name, value, high in zip("PID", (gains.kp, gains.ki, gains.kd), (KP_MAX, KI_MAX, KD_MAX), strict=True):
        if value > high:
            raise UserError(f"--current-gains {text!r}: {name} {value:g} is beyond {high:g}, the most the firmware "
                            "takes")


def plot_file(args: argparse.Namespace) -> Path | None:
    """Where the plot goes (a comparison adds each problem's name to it), or None for --plot none."""
    if args.plot == "none":
        return None
    return Path(args.plot or f"twin-out/twin-tune-{args.plant or Path(args.from_log).stem}.png")


def run(args: argparse.Namespace) -> int:
    check_args(args)
    steps = Steps(args.progress)
    loops = ("marlin", "klipper") if args.loop == BOTH else (args.loop,)
    try:
        plant = source(args, steps)
    except NoModel as exc:  # the log reads and fits, but no plant replays it: a verdict without a model
        print("\n".join(exc.allowed.lines()))
        printer = given_gains(args) or exc.printer
        status, lines = no_model_lines(exc, printer)
        print("\n".join(lines))
        if status == EXIT_NO_MODEL:
            print(f"twin-tune: {exc}", file=sys.stderr)
        if args.json:
            write_no_model_json(Path(args.json), exc, printer)
        return status
    printer = yours(args, plant)
    problems = [make_problem(args, plant, loop, name) for name in args.controller.split(",") for loop in loops]
    print("\n".join(plant_lines(plant)))
    client = None
    if args.dask:
        from distributed import Client

        client = Client(args.dask)
    outcomes = [tune_one(args, problem, is_bed, client, printer, steps) for problem, is_bed in problems]
    if len(outcomes) > 1:
        print("\n".join(comparison(outcomes)))
    if args.json:
        write_json(Path(args.json), outcomes[0], plant, printer, plot_file(args))
    return max(status for status, _, _ in outcomes)


def tune_one(args: argparse.Namespace, problem: Problem, is_bed: bool, client, printer: PrinterGains | None,
             steps: Steps) -> tuple[int, TuneResult, Proven | None]:
    """Tune, prove, report and plot one problem: (the exit status, EPILOG; the tune; its proof)."""
    started = time.perf_counter()
    mine = None if printer is None or not problem.controller.pid else \
        np.array([printer.gains.kp, printer.gains.ki, printer.gains.kd])
    result = tune(problem, args.objective, args.method, args.budget, args.seed, client, yours=mine, on_step=steps)
    for note in result.notes:
        print(f"twin-tune: {note}", file=sys.stderr)
    proof = proven(result, args.proof, cross_check_s=args.cross_check, on_step=steps) \
        if args.proof and problem.loop != "ideal" else None
    status = report(result, proof, args.proof, is_bed, printer)
    if (path := plot_file(args)) is not None:
        several = args.loop == BOTH or "," in args.controller
        suffix = f"-{problem.controller.name}-{problem.loop}" if several else ""
        path = path.with_name(f"{path.stem}{suffix}{path.suffix}")
        write_plot(path, result, f"{problem.name}: {problem.controller.name}, {args.objective} on the "
                                 f"{problem.loop} loop")
        print(f"plot: {path}")
    print(f"({time.perf_counter() - started:.1f} s)", file=sys.stderr)
    return status, result, proof


def comparison(outcomes: list[tuple[int, TuneResult, Proven | None]]) -> list[str]:
    """Controllers (and loops) side by side on the same plant and scenario: each one's answer, its
    cost on the same ensemble and statistic, and its proof."""
    lines = ["comparison on the same plant, scenario and ensemble (cost: the same statistic):"]
    for _, result, proof in outcomes:
        answer = result.best if proof is None else proof.answer or proof.yours
        rows = [] if proof is None else [r for r in proof.rows if r.method == answer.method]
        proved = "unproven" if proof is None else \
            f"{sum(r.trips for r in rows)} trips of {sum(r.runs for r in rows)}, overshoot worst " \
            f"{max(r.overshoot_c[1] for r in rows):.2f} C, hold |e| worst {max(r.hold_error_c[1] for r in rows):.2f} C"
        name = f"{result.problem.controller.name} ({result.problem.loop})"
        kept = "" if proof is None or not proof.verdict.keep else " (kept)"
        lines.append(f"  {name:<22} {answer.method + kept + ' cost ' + format(answer.cost, '.4g'):<32} {proved}")
    return lines


def write_json(path: Path, outcome: tuple[int, TuneResult, Proven | None], plant: Source,
               printer: PrinterGains | None, plot: Path | None) -> None:
    """The answer for a program (the OctoPrint plugin): the verdict, why, the gains, the commands to send,
    the plants and the proof's rows."""
    _, result, proof = outcome
    problem = result.problem
    heater = "heater_bed" if plant.is_bed else "extruder"
    answer = None if proof is None else proof.answer
    verdict = "unproven" if proof is None else proof.verdict.kind

    def gains(c: Candidate) -> dict[str, float]:
        return {"kp": float(c.params[0]), "ki": float(c.params[1]), "kd": float(c.params[2])}

    pid = problem.controller.pid
    document = {
        "verdict": verdict, "why": "" if proof is None else proof.verdict.why, "heater": heater,
        "target_c": problem.scenario.target_c, "loop": problem.loop,
        "current": None if printer is None else {**gains(result.yours), "source": printer.source},
        "answer": gains(answer) if answer is not None and pid else None,
        "commands": [answer.gains.marlin_command(bed=plant.is_bed), "M500"]
        if answer is not None and pid and problem.loop == "marlin" else [],
        "option": _option(proof, pid, plant.is_bed, problem.loop),
        "members": [{"label": p.label, "delta": p.delta, "replay": p.replay.text() if p.replay else ""}
                    for p in plant.allowed.members] if plant.allowed is not None else
        [{"label": m.label, "delta": 0.0, "replay": ""} for m in problem.ensemble.members] if problem.ensemble else [],
        "proof": [] if proof is None else [
            {"member": r.member, "candidate": "yours" if r.method == proof.yours.method else
             "answer" if answer is not None and r.method == answer.method else r.method,
             "runs": r.runs, "trips": r.trips, "overshoot_c": list(r.overshoot_c), "hold_error_c": list(r.hold_error_c),
             "chatter": list(r.chatter), "limit_cycles": r.limit_cycles, "limit_cycle_c": r.limit_cycle_c}
            for r in proof.rows],
        "plot": None if plot is None else str(plot),
    }
    path.write_text(json.dumps(document, indent=1) + "\n")


def _option(proof: Proven | None, pid: bool, is_bed: bool, loop: str) -> dict | None:
    """Under keep your gains, the closest candidate that never trips: its gains, trade and Marlin commands."""
    if proof is None or not proof.verdict.trade or not pid or proof.verdict.shown is None:
        return None
    row = next(r for r in proof.rows if r.method == proof.verdict.shown)
    gains = Gains(*(float(v) for v in row.params))
    return {"method": row.method, "kp": gains.kp, "ki": gains.ki, "kd": gains.kd, "trade": proof.verdict.trade,
            "commands": [gains.marlin_command(bed=is_bed), "M500"] if loop == "marlin" else []}


def write_no_model_json(path: Path, error: NoModel, printer: PrinterGains | None) -> None:
    """write_json's document where no plant the log allows: keep your gains (or no answer), why, no proof."""
    current = None if printer is None else {"kp": printer.gains.kp, "ki": printer.gains.ki, "kd": printer.gains.kd,
                                            "source": printer.source}
    document: dict[str, object] = {
                "verdict": KEEP if printer is not None else "none",
                "why": f"{CANNOT_MODEL}: {error.allowed.why_none()}",
                "heater": error.allowed.heater, "target_c": None, "loop": None, "current": current, "answer": None,
                "option": None, "commands": [], "members": [], "proof": [], "plot": None}
    path.write_text(json.dumps(document, indent=1) + "\n")


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed on one line
        return int(exc.code or 0)
    return run_main("twin-tune", lambda: run(args), errors=(LogError, NotFittable, UserError))


if __name__ == "__main__":
    raise SystemExit(main())
