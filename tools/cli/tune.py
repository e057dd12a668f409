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
from pathlib import Path

from tools.cli.args import check_output, finite_float, output_file, plot_path
from tools.progress import PROGRESS_MODES
from twin.limits import NOISE_MAX_LSB, SEED_MAX, UserError
from tools.entry import OneLineParser, run_main
from tools.tuning.controllers import controller_names
from tools.ident.segments import NotFittable
from tools.logs import LogError
from tools.tuning.ensemble import DEFAULT_NOISE_LSB, DEFAULT_SPREAD, DEFAULT_STATISTIC, STATISTICS
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX
from tools.tuning.defaults import (
    BED_TARGET_C,
    CROSS_CHECK_S,
    DEFAULT_BUDGET,
    DEFAULT_OBJECTIVE,
    EXIT_CODES,
    HOTEND_TARGET_C,
    LOOPS,
    LOOP_AUTO,
    LOOP_BOTH,
    PROOF_SEEDS,
    methods,
)
from tools.tuning.objectives import OBJECTIVES
from tools.tuning.reference import parse_gains
from twin.plants import SPECS

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
    parser.add_argument("--loop", default=LOOP_AUTO, choices=(LOOP_AUTO,) + LOOPS + (LOOP_BOTH,),
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
                             "step of work, 'progress: <step> <done>/<total>', each followed by the whole run's "
                             "'run: <percent>%% [about <s> s left]: <step in a user's words>' (lines: for a program "
                             "reading it)")
    parser.add_argument("--model", metavar="MODEL",
                        help=f"--from-log: the model to fit, one of {', '.join(MODELS)} (default: as twin-fit, "
                             "two_node for a trace, three_node for an M303 capture)")
    parser.add_argument("--heater", help="--from-log: extruder or heater_bed (default: the log's first)")
    parser.add_argument("--segment", type=int, help="--from-log: the segment to fit (default: the longest heat-up)")
    parser.add_argument("--plot", help="plot file (default twin-out/twin-tune-<plant>.png); 'none' for no plot")
    parser.add_argument("--plot-compact", metavar="FILE", type=plot_path,
                        help="also a compact figure for a narrow page (OctoPrint's tab): your gains against the "
                             "answer on the nominal plant, temperature and duty")
    parser.add_argument("--plot-history", action="store_true",
                        help="add a panel of each optimiser's best cost per iteration to the plot")
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
    from tools.cli.tune_work import tune_all  # the tuning layer (numba, scipy): not at --help

    return tune_all(args, plot_file(args))


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed on one line
        return int(exc.code or 0)
    return run_main("twin-tune", lambda: run(args), errors=(LogError, NotFittable, UserError))


if __name__ == "__main__":
    raise SystemExit(main())
