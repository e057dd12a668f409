"""twin-tune: tune a heater controller on the firmware in the loop; print its settings ready to paste.

The plant is a preset (``--plant``) or fitted to a log as twin-fit does (``--from-log``); the
controller is a firmware build with parameters (``--controller``, default Marlin's fixed-point
PID) or your own ``module:attribute`` naming a firmware_port.params.ParamSpace. Every candidate
(the tuning rules for a PID, an optimiser's search) runs the same scenario in the loop
(tools/tuning/evaluate.py: heat-up, then disturbances) and is scored by the objective
(tools/tuning/objectives.py). The best is printed first with its settings, then every candidate
beside the references (the controller's defaults and, for a PID, the firmware's own autotune on
the same twin: Marlin M303 C8 or Klipper PID_CALIBRATE), and a plot of the responses is written.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from tools.cli.args import OneLineParser, finite_float, plot_path
from tools.cli.entry import run_main
from tools.tuning.controllers import controller_names, resolve_controller
from tools.tuning.evaluate import AMBIENT_C, LOOPS, Candidate, Problem, default_scenario, heater_of
from tools.tuning.objectives import DEFAULT_OBJECTIVE, OBJECTIVES, heater_terms
from tools.tuning.tuner import DEFAULT_BUDGET, TuneResult, methods, tune
from twin.metrics import step_metrics
from twin.plants import SPECS, Spec

BED_TARGET_C, HOTEND_TARGET_C = 60.0, 210.0
MODELS = ("two_node", "three_node", "fopdt", "sopdt")
EPILOG = """examples:
  twin-tune --plant hotend_cartridge --target 210            # rules, then DE, against M303 C8
  twin-tune --plant hotend_cartridge --method ocalo --budget 900 --seed 1
  twin-tune --controller fuzzy_pi --plant bed --target 60    # seed 004's fuzzy PI: its three ranges
  twin-tune --controller my_module:SPACE --plant hotend      # your own controller (a ParamSpace)
  twin-tune --from-log klippy.log --heater extruder --loop klipper
"""


# -- the plant ---------------------------------------------------------------------------------
def plant_from_log(args: argparse.Namespace) -> tuple[str, Spec, bool]:
    """Fit the log as twin-fit does: (a name, the fitted spec, whether it is a bed)."""
    from tools.cli.fit import ASSUMED_POWER_W, BED
    from tools.ident.fit import default_segment, fit_model, log_segments
    from tools.logs import load_log
    from twin.plants import MPC_HEATER_POWER_W

    log = load_log(args.from_log)
    heater, segments = log_segments(log, args.heater, None)
    chosen = default_segment(segments) if args.segment is None else args.segment
    if not 0 <= chosen < len(segments):
        raise ValueError(f"--segment {chosen}: the segments are 0..{len(segments) - 1}")
    seg = segments[chosen]
    power_w = ASSUMED_POWER_W.get(heater, MPC_HEATER_POWER_W) if args.model in ("two_node", "three_node") else None
    result = fit_model(args.model, seg.t_s, seg.temp_c, seg.duty, None, power_w=power_w)
    name = f"{Path(args.from_log).name} ({args.model}, segment {chosen}, RMSE {result.rmse_c:.2f} C)"
    return name, result.spec(), heater == BED


def make_problem(args: argparse.Namespace) -> tuple[Problem, bool]:
    """The problem the arguments describe, and whether its heater is a bed."""
    if args.from_log:
        name, spec, is_bed = plant_from_log(args)
    else:
        if args.plant not in SPECS:
            raise ValueError(f"--plant {args.plant!r}: valid presets: {', '.join(SPECS)}")
        name, spec, is_bed = args.plant, SPECS[args.plant], heater_of(args.plant) == "bed"
    target_c = args.target if args.target is not None else (BED_TARGET_C if is_bed else HOTEND_TARGET_C)
    if target_c <= AMBIENT_C:
        raise ValueError(f"--target {target_c:g}: a heater tune needs a target above the ambient {AMBIENT_C:g} C")
    try:
        scenario = default_scenario(spec, target_c)
    except ValueError as exc:
        raise ValueError(f"--target {target_c:g}: {exc}") from None
    controller = resolve_controller(args.controller, "bed" if is_bed else "hotend")
    try:
        problem = Problem(name, spec, scenario, args.loop, controller)
    except ValueError as exc:
        raise ValueError(f"--loop {args.loop}: {exc}") from None
    return problem, is_bed


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
    """Ready to paste: Marlin's M301/M304 and Configuration.h, Klipper's section; or the parameters."""
    if not problem.controller.pid:
        return [f"{problem.controller.name} parameters (the firmware's units):",
                *(f"  {p.name} = {v:.6g} {p.unit}".rstrip() for p, v in zip(problem.controller.params, best.params))]
    gains, heater = best.gains, "heater_bed" if is_bed else "extruder"
    return ["Marlin (send, then M500 to keep it):", f"  {gains.marlin_command(bed=is_bed)}", "  M500",
            "Marlin Configuration.h:", *("  " + line for line in gains.marlin_defines(bed=is_bed).splitlines()),
            "Klipper printer.cfg:", *("  " + line for line in gains.klipper_section(heater).splitlines())]


def report(result: TuneResult, is_bed: bool) -> None:
    problem, best = result.problem, result.best
    print(f"twin-tune: {problem.name} at {problem.scenario.target_c:g} C, controller {problem.controller.name}, "
          f"objective {result.objective}, loop {problem.loop}")
    versus = "; ".join(f"{'beats' if result.beats(r) else 'does not beat'} {r.method}: {describe(problem, r)}  "
                       f"cost {r.cost:.4g}" for r in result.references)
    print(f"best: {best.method}  {describe(problem, best)}  cost {best.cost:.4g}  ({versus})")
    by_rule = [c for c in result.candidates if c.history is None]
    if by_rule and by_rule[0] is not best:
        print(f"best rule: {by_rule[0].method}  {describe(problem, by_rule[0])}  cost {by_rule[0].cost:.4g}")
    print("\n".join(settings_lines(problem, best, is_bed)))
    print(f"candidates on the {problem.loop} loop (best first), then the references:")
    shown = result.candidates + result.references
    width = max(len(c.method) for c in shown)
    texts = [describe(problem, c) for c in shown]
    text_width = max(len(t) for t in texts)
    for c, text in zip(shown, texts):
        mark = "*" if c is best else " "
        print(f" {mark}{c.method:{width}}  {text:{text_width}}  cost {c.cost:10.4g}  {metrics_line(c)}")


def write_plot(path: Path, result: TuneResult, title: str) -> None:
    """Responses of the best candidates and the references; the convergence of any optimiser."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    candidates = result.candidates
    shown = candidates[:4] + result.references
    searched = [c for c in candidates if c.history is not None]
    fig, axes = plt.subplots(1 + bool(searched), 1, figsize=(10, 6 + 3 * bool(searched)), squeeze=False)
    ax = axes[0, 0]
    for c in shown:
        ax.plot(c.run.t_s, c.run.temp_c[:, 0], lw=1.2 if c is candidates[0] else 0.8,
                label=f"{c.method}: {describe(result.problem, c)} (cost {c.cost:.4g})")
    ax.axhline(candidates[0].run.target_c, color="k", ls=":", lw=0.8)
    for t_s in candidates[0].run.disturbances_s:
        ax.axvline(t_s, color="grey", ls="--", lw=0.6)
    ax.set(xlabel="time (s)", ylabel="measured temperature (C)", title=title)
    ax.legend(fontsize=8)
    if searched:
        for c in searched:
            axes[1, 0].semilogy(c.history, label=c.method)
        axes[1, 0].set(xlabel="iteration", ylabel="best cost")
        axes[1, 0].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# -- the command ----------------------------------------------------------------------------------
def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = OneLineParser(prog="twin-tune", description=__doc__.split("\n\n")[0], epilog=EPILOG)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--plant", help=f"a plant preset: {', '.join(SPECS)}")
    source.add_argument("--from-log", metavar="LOG", help="fit a plant to this log (as twin-fit), then tune it")
    parser.add_argument("--target", type=finite_float, help=f"setpoint in C (default {HOTEND_TARGET_C:g}, a bed "
                        f"{BED_TARGET_C:g})")
    parser.add_argument("--controller", default="pid", metavar="NAME",
                        help=f"a firmware build with parameters ({', '.join(controller_names())}) or a "
                             "module:attribute naming your ParamSpace (default: pid)")
    parser.add_argument("--loop", default="marlin", choices=LOOPS,
                        help="the loop the candidates run in: Marlin's board, Klipper's host PID, or the papers' "
                             "idealised continuous loop (default: marlin)")
    parser.add_argument("--ideal", action="store_const", dest="loop", const="ideal", help="same as --loop ideal")
    parser.add_argument("--method", default="auto", metavar="METHOD",
                        help=f"one of: {', '.join(methods())}. 'all': every rule and optimiser; 'auto' (default): "
                             "every rule (a PID), then DE")
    parser.add_argument("--objective", default=DEFAULT_OBJECTIVE, metavar="NAME",
                        help=f"one of: {', '.join(OBJECTIVES)} (default: {DEFAULT_OBJECTIVE})")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET,
                        help=f"objective evaluations per optimiser (default: {DEFAULT_BUDGET})")
    parser.add_argument("--seed", type=int, default=0, help="optimiser random seed (default: 0)")
    parser.add_argument("--model", default="two_node", metavar="MODEL",
                        help=f"--from-log: the model to fit, one of {', '.join(MODELS)} (default: two_node)")
    parser.add_argument("--heater", help="--from-log: extruder or heater_bed (default: the log's first)")
    parser.add_argument("--segment", type=int, help="--from-log: the segment to fit (default: the longest heat-up)")
    parser.add_argument("--plot", help="plot file (default twin-out/twin-tune-<plant>.png); 'none' for no plot")
    parser.add_argument("--dask", metavar="ADDRESS", help="a dask.distributed scheduler (tcp://host:port)")
    return parser.parse_args(argv)


def check_args(args: argparse.Namespace) -> None:
    if args.objective not in OBJECTIVES:
        raise ValueError(f"--objective {args.objective!r}: choose one of: {', '.join(OBJECTIVES)}")
    if args.budget < 1:
        raise ValueError(f"--budget {args.budget}: must be at least 1")
    if args.method not in methods():
        raise ValueError(f"--method {args.method!r}: choose one of: {', '.join(methods())}")
    if args.model not in MODELS:
        raise ValueError(f"--model {args.model!r}: choose one of: {', '.join(MODELS)}")
    if args.plot not in (None, "none"):
        try:
            plot_path(args.plot)
        except argparse.ArgumentTypeError as exc:
            raise ValueError(f"--plot {args.plot}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    check_args(args)
    problem, is_bed = make_problem(args)
    client = None
    if args.dask:
        from distributed import Client

        client = Client(args.dask)
    started = time.perf_counter()
    result = tune(problem, args.objective, args.method, args.budget, args.seed, client, progress=True)
    for note in result.notes:
        print(f"twin-tune: {note}", file=sys.stderr)
    report(result, is_bed)
    if args.plot != "none":
        stem = args.plant or Path(args.from_log).stem
        path = Path(args.plot or f"twin-out/twin-tune-{stem}.png")
        write_plot(path, result, f"{problem.name}: {problem.controller.name}, {args.objective} on the "
                                 f"{problem.loop} loop")
        print(f"plot: {path}")
    print(f"({time.perf_counter() - started:.1f} s)", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed on one line
        return int(exc.code or 0)
    return run_main("twin-tune", lambda: run(args))


if __name__ == "__main__":
    raise SystemExit(main())
