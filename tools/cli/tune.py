"""twin-tune: tune a heater's PID on the firmware in the loop; print gains ready to paste.

The plant is a preset (``--plant``) or fitted to a log as twin-fit does (``--from-log``). Every
candidate (the tuning rules of tools/tuning/rules, an optimiser's search) runs the same scenario
on the firmware twin (tools/tuning/evaluate.py: heat-up, then disturbances) and is scored by the
objective (tools/tuning/objectives.py, default ``heater``). The best is printed first with its
settings (M301 + M500, Configuration.h defines, a Klipper section), then every candidate next to
the firmware's own autotune on the same twin (Marlin M303 C8 or Klipper PID_CALIBRATE), and a
plot of the responses (and the optimiser's convergence) is written.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from tools.tuning.evaluate import (
    GAIN_MAX,
    Candidate,
    Evaluator,
    Problem,
    default_scenario,
    firmware_autotune,
    optimiser_names,
    rule_gains,
    rule_names,
    score,
    simulate,
)
from tools.tuning.gains import Gains
from tools.tuning.optim import METHODS
from tools.tuning.objectives import DEFAULT_OBJECTIVE, OBJECTIVES, Run, heater_terms, objective
from twin.metrics import step_metrics
from twin.plants import SPECS, Spec

FIRMWARES = ("marlin", "klipper")  # --firmware: also the name of the evaluation loop
BED_TARGET_C, HOTEND_TARGET_C = 60.0, 210.0
DEFAULT_BUDGET = 900  # optimiser evaluations: 20 generations of DE's default population of 45
SEARCH_FACTOR = 4.0  # optimiser bounds: 0 .. 4 x the best rule's gains (capped at the firmware's range)
MIN_BOUND = np.array([1.0, 0.05, 1.0])  # so a rule's zero Ki or Kd still leaves room to search


# -- the plant ---------------------------------------------------------------------------------
def plant_from_log(args: argparse.Namespace) -> tuple[str, Spec, bool]:
    """Fit the log as twin-fit does: (a name, the fitted spec, whether it is a bed)."""
    from tools.ident.log_fit import ASSUMED_POWER_W, BED
    from tools.ident.fit import fit_model
    from tools.ident.segments import default_segment, log_segments
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
        name, spec, is_bed = args.plant, SPECS[args.plant], args.plant.startswith("bed")
    target_c = args.target if args.target is not None else (BED_TARGET_C if is_bed else HOTEND_TARGET_C)
    try:
        scenario = default_scenario(spec, target_c)
    except ValueError as exc:
        raise ValueError(f"--target {target_c:g}: {exc}") from None
    return Problem(name, spec, scenario, "ideal" if args.ideal else args.firmware), is_bed


# -- candidates ---------------------------------------------------------------------------------
def search_bounds(start: Gains) -> list[tuple[float, float]]:
    top = np.minimum(np.maximum(SEARCH_FACTOR * np.array([start.kp, start.ki, start.kd]), MIN_BOUND), GAIN_MAX)
    return [(0.0, float(t)) for t in top]


def optimise(problem: Problem, cost: Callable[[Run], np.ndarray], method: str, start: Gains, budget: int,
             seed: int, client=None, progress=None) -> Candidate:
    """Search with an optimiser of tools/tuning/optim on the firmware twin, within search_bounds(start)."""
    evaluator = Evaluator(problem, cost, client, on_batch=progress)
    try:
        result = METHODS[method](evaluator, search_bounds(start), rng=np.random.default_rng(seed), budget=budget)
    except ValueError as exc:  # e.g. a budget below two of the optimiser's generations
        raise ValueError(f"--method {method} --budget {budget}: {exc}") from None
    best = Gains(*np.clip(result.x, 0.0, GAIN_MAX))
    run = simulate(problem, [[best.kp, best.ki, best.kd]], client)
    return Candidate(method, best, float(cost(run)[0]), run, np.asarray(result.history, float))


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


def settings_lines(gains: Gains, is_bed: bool) -> list[str]:
    heater = "heater_bed" if is_bed else "extruder"
    return ["Marlin (send, then M500 to keep it):", f"  {gains.marlin_command(bed=is_bed)}", "  M500",
            "Marlin Configuration.h:", *("  " + line for line in gains.marlin_defines(bed=is_bed).splitlines()),
            "Klipper printer.cfg:", *("  " + line for line in gains.klipper_section(heater).splitlines())]


def write_plot(path: Path, candidates: list[Candidate], reference: Candidate | str, title: str) -> None:
    """Responses of the best candidates and the reference; the convergence of any optimiser."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = candidates[:4] + ([reference] if isinstance(reference, Candidate) else [])
    searched = [c for c in candidates if c.history is not None]
    fig, axes = plt.subplots(1 + bool(searched), 1, figsize=(10, 6 + 3 * bool(searched)), squeeze=False)
    ax = axes[0, 0]
    for c in shown:
        ax.plot(c.run.t_s, c.run.temp_c[:, 0], lw=1.2 if c is candidates[0] else 0.8,
                label=f"{c.method}: {c.gains} (cost {c.cost:.4g})")
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
    parser = argparse.ArgumentParser(prog="twin-tune", description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--plant", help=f"a plant preset: {', '.join(SPECS)}")
    source.add_argument("--from-log", metavar="LOG", help="fit a plant to this log (as twin-fit), then tune it")
    parser.add_argument("--target", type=float, help=f"setpoint in C (default {HOTEND_TARGET_C:g}, a bed "
                        f"{BED_TARGET_C:g})")
    parser.add_argument("--method", default="auto",
                        help="a rule, an optimiser, 'all' (every rule and optimiser) or 'auto' (default: every "
                             "rule, then the default optimiser from the best rule)")
    parser.add_argument("--objective", default=DEFAULT_OBJECTIVE, help=f"one of: {', '.join(OBJECTIVES)}")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET, help="optimiser evaluations")
    parser.add_argument("--seed", type=int, default=0, help="optimiser random seed")
    parser.add_argument("--firmware", default="marlin", help="marlin or klipper: the controller in the loop")
    parser.add_argument("--ideal", action="store_true", help="score on the papers' idealised linear loop instead")
    parser.add_argument("--model", default="two_node", help="--from-log: the model to fit (as twin-fit)")
    parser.add_argument("--heater", help="--from-log: extruder or heater_bed")
    parser.add_argument("--segment", type=int, help="--from-log: the segment to fit")
    parser.add_argument("--plot", help="plot file (default twin-out/twin-tune-<plant>.png); 'none' for no plot")
    parser.add_argument("--dask", metavar="ADDRESS", help="a dask.distributed scheduler (tcp://host:port)")
    return parser.parse_args(argv)


def check_args(args: argparse.Namespace) -> None:
    if args.firmware not in FIRMWARES:
        raise ValueError(f"--firmware {args.firmware!r}: choose marlin or klipper")
    if args.objective not in OBJECTIVES:
        raise ValueError(f"--objective {args.objective!r}: choose one of: {', '.join(OBJECTIVES)}")
    if args.budget < 1:
        raise ValueError(f"--budget {args.budget}: must be at least 1")
    known = rule_names() + optimiser_names() + ["all", "auto"]
    if args.method not in known:
        raise ValueError(f"--method {args.method!r}: choose one of: {', '.join(known)}")
    if args.model not in ("two_node", "three_node", "fopdt", "sopdt"):
        raise ValueError(f"--model {args.model!r}: choose two_node, three_node, fopdt or sopdt")


def plan(method: str) -> tuple[list[str], list[str]]:
    """(rules, optimisers) that --method asks for."""
    rules, optimisers = rule_names(), optimiser_names()
    if method == "all":
        return rules, optimisers
    if method == "auto":
        return rules, [DEFAULT_OPTIMISER] if DEFAULT_OPTIMISER in optimisers else []
    return ([method], []) if method in rules else ([], [method])


DEFAULT_OPTIMISER = "de"


def progress_bar(total: int):
    """A terminal progress bar on stderr (tqdm hides itself when stderr is not a terminal)."""
    from tqdm import tqdm

    return tqdm(total=total, unit="eval", file=sys.stderr, disable=None, leave=False)


def autotune_reference(problem: Problem, cost: Callable[[Run], np.ndarray], client=None) -> Candidate | str:
    """The firmware's own autotune on the same twin, scored; or why it failed."""
    try:
        name, gains = firmware_autotune(replace(problem, loop="klipper" if problem.loop == "klipper" else "marlin"))
    except ValueError as exc:
        return str(exc)
    return score(problem, cost, {name: gains}, client)[0]


def tune(args: argparse.Namespace, problem: Problem, client=None) -> tuple[list[Candidate], Candidate | str]:
    """Every planned candidate scored, best first, and the firmware's autotune on the same twin."""
    cost = objective(args.objective)
    rules, optimisers = plan(args.method)
    reference = autotune_reference(problem, cost, client)
    gains, failures = rule_gains(problem, rules)
    for rule, why in failures.items():
        print(f"twin-tune: rule {rule} gives no gains here: {why}", file=sys.stderr)
    candidates = score(problem, cost, gains, client) if gains else []
    if candidates:
        start = candidates[0].gains
    elif isinstance(reference, Candidate):
        start = reference.gains
    else:
        raise ValueError(f"--method {args.method}: no rule to start the search from, and {reference}")
    for method in optimisers:
        with progress_bar(args.budget) as bar:
            def step(costs: np.ndarray, bar=bar) -> None:
                bar.update(len(costs))
                bar.set_postfix(best=f"{np.min(costs):.4g}")

            candidates.append(optimise(problem, cost, method, start, args.budget, args.seed, client, step))
    return sorted(candidates, key=lambda c: c.cost), reference


def report(args: argparse.Namespace, problem: Problem, is_bed: bool, candidates: list[Candidate],
           reference: Candidate | str) -> None:
    best = candidates[0]
    print(f"twin-tune: {problem.name} at {problem.scenario.target_c:g} C, objective {args.objective}, "
          f"loop {problem.loop}")
    if isinstance(reference, Candidate):
        verdict = "beats" if best.cost < reference.cost else "does not beat"
        versus = f"{verdict} {reference.method}: {reference.gains}  cost {reference.cost:.4g}"
        shown = candidates + [reference]
    else:
        versus, shown = reference, candidates
    print(f"best: {best.method}  {best.gains}  cost {best.cost:.4g}  ({versus})")
    by_rule = [c for c in candidates if c.history is None]
    if by_rule and by_rule[0] is not best:
        print(f"best rule: {by_rule[0].method}  {by_rule[0].gains}  cost {by_rule[0].cost:.4g}")
    print("\n".join(settings_lines(best.gains, is_bed)))
    print(f"candidates on the {problem.loop} loop (best first):")
    width = max(len(c.method) for c in shown)
    for c in shown:
        mark = "*" if c is best else " "
        print(f" {mark}{c.method:{width}}  {str(c.gains):36}  cost {c.cost:10.4g}  {metrics_line(c)}")


def run(args: argparse.Namespace) -> int:
    check_args(args)
    problem, is_bed = make_problem(args)
    client = None
    if args.dask:
        from distributed import Client

        client = Client(args.dask)
    started = time.perf_counter()
    candidates, reference = tune(args, problem, client)
    report(args, problem, is_bed, candidates, reference)
    if args.plot != "none":
        stem = args.plant or Path(args.from_log).stem
        path = Path(args.plot or f"twin-out/twin-tune-{stem}.png")
        write_plot(path, candidates, reference, f"{problem.name}: {args.objective} on the {problem.loop} loop")
        print(f"plot: {path}")
    print(f"({time.perf_counter() - started:.1f} s)", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        return run(args)
    except BrokenPipeError:
        sys.stdout = None
        return 0
    except OSError as exc:
        print(f"twin-tune: error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
    except ValueError as exc:
        print(f"twin-tune: error: {exc}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
