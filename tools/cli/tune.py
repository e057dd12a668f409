"""twin-tune: tune a heater controller on the firmware in the loop; print its settings ready to paste.

The plant is a preset (``--plant``) or fitted to a log as twin-fit does (``--from-log``); the
controller is a firmware build with parameters (``--controller``, default Marlin's fixed-point
PID) or your own ``module:attribute`` naming a firmware_port.params.ParamSpace. Every candidate
(the tuning rules for a PID, an optimiser's search) runs the same scenario in the loop
(tools/tuning/evaluate.py: heat-up, then disturbances) on every plant of an ensemble (the nominal
plant and the corners of its spread, each with ADC noise: tools/tuning/ensemble.py), scored by the
objective (tools/tuning/objectives.py) and reduced to a robust statistic. The best is then proven
on the reference engine over many noise seeds and the extreme plants, beside the firmware's own
autotune (tools/tuning/proof.py); only a candidate that never trips is printed ready to paste.
Every candidate follows beside the references (the controller's defaults and, for a PID, Marlin
M303 C8 or Klipper PID_CALIBRATE on the same twin), and a plot of the responses is written.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from tools.cli.args import check_output, finite_float, plot_path
from twin.limits import NOISE_MAX_LSB, SEED_MAX
from tools.entry import OneLineParser, run_main
from tools.tuning.controllers import controller_names
from tools.ident.log_fit import LogFitOptions
from tools.tuning.ensemble import DEFAULT_NOISE_LSB, DEFAULT_SPREAD, DEFAULT_STATISTIC, STATISTICS
from tools.tuning.evaluate import LOOPS, Candidate, Problem
from tools.tuning.problems import BED_TARGET_C, HOTEND_TARGET_C, Source, build_problem, log_source, preset_source
from tools.tuning.objectives import DEFAULT_OBJECTIVE, OBJECTIVES, heater_terms
from tools.tuning.proof import PROOF_SEEDS, ProofRow
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

exit status:
  0  tuned, and a candidate passed the proof
  1  tuned, but no candidate passed the proof (the report says why)
  2  bad input (an option, a log, a controller), said in one line; nothing is tuned
"""


# -- the plant ---------------------------------------------------------------------------------
def source(args: argparse.Namespace) -> Source:
    """The plant: a preset, or the log fitted exactly as twin-fit fits it (tools/ident/log_fit.py)."""
    if not args.from_log:
        return preset_source(args.plant, args.spread)
    options = LogFitOptions(model=args.model, heater=args.heater, segment=args.segment)
    return log_source(args.from_log, options)


def make_problem(args: argparse.Namespace, plant: Source, loop: str, controller_name: str) -> tuple[Problem, bool]:
    """The problem the arguments describe on ``plant`` (with ``loop`` and ``controller_name``), and whether its
    heater is a bed."""
    problem = build_problem(plant, args.target, controller_name, loop, args.noise, args.statistic,
                            spread=args.spread > 0)
    return problem, plant.is_bed


def plant_lines(plant: Source) -> list[str]:
    """A fitted plant's parameters, exactly as twin-fit prints them."""
    if plant.fitted is None:
        return []
    result = plant.fitted.result
    return [f"plant: {result.model} fitted to {plant.name.split(' (')[0]} as twin-fit fits it:",
            *result.parameter_lines()]


# -- output -------------------------------------------------------------------------------------
def metrics_line(candidate: Candidate) -> str:
    """Heat-up metrics (twin/metrics.py) and the heater objective's terms of one candidate."""
    run = candidate.run
    heat = run.t_s < run.heatup_end_s
    m = step_metrics(run.t_s[heat], run.temp_c[heat, 0], run.target_c, np.clip(run.duty[heat, 0], 0, 1))
    terms = heater_terms(run)

    def show(value: float | None, unit: str) -> str:
        return "-" if value is None else f"{value:.1f}{unit}"

    return (f"rise {show(m.rise_time_s, ' s')}, overshoot {show(m.overshoot_c, ' C')}, settling(2%) "
            f"{show(m.settling_time_2pct_s, ' s')}, IAE {m.iae_c_s:.0f} C s, ITAE {m.itae_c_s2:.3g} C s^2, "
            f"hold |e| {terms.hold_error_c[0]:.2f} C" + (", PROTECTION TRIP" if terms.tripped[0] else ""))


def describe(problem: Problem, candidate: Candidate) -> str:
    """A candidate's parameters: gains for a PID family, else each parameter with its unit."""
    return str(candidate.gains) if problem.controller.pid else problem.controller.describe(candidate.params)


def settings_lines(problem: Problem, best: Candidate, is_bed: bool) -> list[str]:
    """Ready to paste, for the loop that proved it: Marlin's M301/M304 and Configuration.h, or Klipper's
    section; for other controllers their parameters."""
    if not problem.controller.pid:
        return [f"{problem.controller.name} parameters (the firmware's units), from the {problem.loop} loop:",
                *(f"  {p.name} = {v:.6g} {p.unit}".rstrip() for p, v in zip(problem.controller.params, best.params))]
    gains, heater = best.gains, "heater_bed" if is_bed else "extruder"
    if problem.loop == "klipper":
        return ["Klipper printer.cfg (proven on the Klipper loop):",
                *("  " + line for line in gains.klipper_section(heater).splitlines())]
    where = "proven on the Marlin loop" if problem.loop == "marlin" else "from the papers' idealised loop, unproven"
    return [f"Marlin ({where}; send, then M500 to keep it):", f"  {gains.marlin_command(bed=is_bed)}", "  M500",
            "Marlin Configuration.h:", *("  " + line for line in gains.marlin_defines(bed=is_bed).splitlines())]


def report_proof(problem: Problem, proof: Proven, seeds: int) -> None:
    corners = len(problem.members()) - 1
    print(f"proof on the {'reference engine' if problem.loop == 'marlin' else problem.loop + ' twin'}: "
          f"{seeds} noise seeds on the nominal plant and {corners} corner plants, one run each:")

    def named(row: ProofRow) -> str:
        return problem.controller.describe(row.params) if not problem.controller.pid else \
            f"Kp {row.params[0]:.4g} Ki {row.params[1]:.4g} Kd {row.params[2]:.4g}"

    print("\n".join("  " + line for line in proof_table(proof.rows, named)))


def report(result: TuneResult, proof: Proven | None, seeds: int, is_bed: bool) -> int:
    """Print the tune; the exit status: 1 when no candidate passed the proof."""
    problem, best = result.problem, result.best
    print(f"twin-tune: {problem.name} at {problem.scenario.target_c:g} C, controller {problem.controller.name}, "
          f"objective {result.objective}, loop {problem.loop}")
    if problem.ensemble is not None:
        print(f"ensemble: {problem.ensemble.describe()}")
    versus = "; ".join(f"{'beats' if result.beats(r) else 'does not beat'} {r.method}: {describe(problem, r)}  "
                       f"cost {r.cost:.4g}" for r in result.references if r is not best)
    if best in result.references:
        versus = f"no search beat this reference; {versus}" if versus else "no search beat this reference"
    print(f"best: {best.method}  {describe(problem, best)}  cost {best.cost:.4g}  ({versus})")
    by_rule = [c for c in result.candidates if c.history is None]
    if by_rule and by_rule[0] is not best and problem.controller.pid:
        print(f"best rule: {by_rule[0].method}  {describe(problem, by_rule[0])}  cost {by_rule[0].cost:.4g}")
    answer: Candidate | None = best
    if proof is not None:
        report_proof(problem, proof, seeds)
        answer = proof.answer
    elif problem.loop != "ideal":
        print("not proven (--proof 0)")
    if answer is None:
        print("no candidate passed the proof: every one tried trips in some run; nothing to paste")
    else:
        if answer is not best:
            print(f"answer: {answer.method} (better candidates tripped in the proof)")
        print("\n".join(settings_lines(problem, answer, is_bed)))
    print(f"candidates on the {problem.loop} loop (best first), then the references; cost = {_statistic(problem)}:")
    shown = result.candidates + result.references
    width = max(len(c.method) for c in shown)
    texts = [describe(problem, c) for c in shown]
    text_width = max(len(t) for t in texts)
    for c, text in zip(shown, texts):
        mark = "*" if c is answer else " "
        print(f" {mark}{c.method:{width}}  {text:{text_width}}  cost {c.cost:10.4g}  {metrics_line(c)}")
    return 0 if answer is not None else 1


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
    parser.add_argument("--loop", default="marlin", choices=LOOPS + (BOTH,),
                        help="the loop the candidates run in: Marlin's board, Klipper's host PID, the papers' "
                             "idealised continuous loop, or both firmware loops, each with its own answer "
                             "(default: marlin)")
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
                             f"(default: {DEFAULT_SPREAD:g}; 0: the nominal plant only)")
    parser.add_argument("--statistic", default=DEFAULT_STATISTIC, choices=STATISTICS,
                        help=f"how the members' costs reduce to one (default: {DEFAULT_STATISTIC})")
    parser.add_argument("--proof", type=int, default=PROOF_SEEDS, metavar="SEEDS",
                        help=f"prove the answer on the reference engine over SEEDS noise seeds and the corner plants "
                             f"(default: {PROOF_SEEDS}; 0: skip)")
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
        raise ValueError(f"--objective {args.objective!r}: choose one of: {', '.join(OBJECTIVES)}")
    if not 1 <= args.budget <= BUDGET_MAX:
        raise ValueError(f"--budget {args.budget}: must be within 1 .. {BUDGET_MAX}")
    if args.noise is not None and not 0 <= args.noise <= NOISE_MAX_LSB:
        raise ValueError(f"--noise {args.noise:g}: must be within 0 .. {NOISE_MAX_LSB:g} LSB")
    if not 0 <= args.spread < 1:
        raise ValueError(f"--spread {args.spread:g}: must be within 0 .. 1 (a fraction)")
    if not 0 <= args.proof <= PROOF_MAX:
        raise ValueError(f"--proof {args.proof}: must be within 0 .. {PROOF_MAX} seeds")
    if not 0 <= args.seed <= SEED_MAX:
        raise ValueError(f"--seed {args.seed}: must be a whole number >= 0 (below 2**63)")
    if args.method not in methods():
        raise ValueError(f"--method {args.method!r}: choose one of: {', '.join(methods())}")
    if args.model is not None and args.model not in MODELS:
        raise ValueError(f"--model {args.model!r}: choose one of: {', '.join(MODELS)}")
    path = plot_file(args)
    try:
        if path is not None and args.plot is None and not path.parent.exists():
            check_output(path.parent)  # the default folder, made at the end: it can be
        elif path is not None:
            plot_path(str(path))
    except (argparse.ArgumentTypeError, ValueError) as exc:
        raise ValueError(f"--plot {path}: {exc}") from None


def plot_file(args: argparse.Namespace) -> Path | None:
    """Where the plot goes (a comparison adds each problem's name to it), or None for --plot none."""
    if args.plot == "none":
        return None
    return Path(args.plot or f"twin-out/twin-tune-{args.plant or Path(args.from_log).stem}.png")


def run(args: argparse.Namespace) -> int:
    check_args(args)
    loops = ("marlin", "klipper") if args.loop == BOTH else (args.loop,)
    plant = source(args)
    problems = [make_problem(args, plant, loop, name) for name in args.controller.split(",") for loop in loops]
    print("\n".join(plant_lines(plant)))
    client = None
    if args.dask:
        from distributed import Client

        client = Client(args.dask)
    outcomes = [tune_one(args, problem, is_bed, client) for problem, is_bed in problems]
    if len(outcomes) > 1:
        print("\n".join(comparison(outcomes)))
    return max(status for status, _, _ in outcomes)


def tune_one(args: argparse.Namespace, problem: Problem, is_bed: bool, client
             ) -> tuple[int, TuneResult, Proven | None]:
    """Tune, prove, report and plot one problem: (the exit status, 1 when nothing passed the proof; the
    tune; its proof)."""
    started = time.perf_counter()
    result = tune(problem, args.objective, args.method, args.budget, args.seed, client, progress=True)
    for note in result.notes:
        print(f"twin-tune: {note}", file=sys.stderr)
    proof = proven(result, args.proof) if args.proof and problem.loop != "ideal" else None
    status = report(result, proof, args.proof, is_bed)
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
        answer = result.best if proof is None else proof.answer
        row = None if proof is None or answer is None else next(r for r in proof.rows if r.method == answer.method)
        proved = "unproven" if proof is None else "nothing passed" if row is None else \
            f"{row.trips} trips of {row.runs}, overshoot {row.overshoot_c[0]:.2f} / {row.overshoot_c[1]:.2f} C, " \
            f"hold |e| {row.hold_error_c[0]:.2f} / {row.hold_error_c[1]:.2f} C (mean / worst)"
        name = f"{result.problem.controller.name} ({result.problem.loop})"
        cost = "-" if answer is None else f"{answer.method} cost {answer.cost:.4g}"
        lines.append(f"  {name:<22} {cost:<26} {proved}")
    return lines


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed on one line
        return int(exc.code or 0)
    return run_main("twin-tune", lambda: run(args))


if __name__ == "__main__":
    raise SystemExit(main())
