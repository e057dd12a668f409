"""twin-tune's work once its arguments are checked (tools/cli/tune.py): the plants, each tune, the
report, the JSON and the plot. Imported when a tune runs, so that ``twin-tune --help`` loads no tuning layer."""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np

from tools.plots import tab_figure, tune_figure
from tools.progress import Steps
from tools.ident.log_fit import LogFitOptions
from firmware_port.firmwares import KALICO_MPC
from tools.tuning.evaluate import Candidate, Problem
from tools.tuning.answer import CANNOT_MODEL, no_model_lines, printer_params, settings_lines, verdict_lines
from tools.tuning.defaults import EXIT_ANSWER, EXIT_NO_MODEL, LOOP_AUTO, LOOP_BOTH
from tools.tuning.gains import Gains
from tools.tuning.verdict import KEEP
from tools.tuning.problems import (
    NoModel,
    Source,
    build_problem,
    log_source,
    preset_source,
)
from tools.tuning.objectives import heater_terms
from tools.tuning.proof import ProofRow
from tools.tuning.reference import PrinterGains, parse_gains
from tools.tuning.proof import table as proof_table
from tools.tuning.tuner import Proven, TuneResult, proven, tune
from twin.metrics import step_metrics


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
    problem = build_problem(plant, args.target, controller_name, None if loop == LOOP_AUTO else loop, args.noise,
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


# -- the command ----------------------------------------------------------------------------------
def tune_all(args: argparse.Namespace, plot: Path | None) -> int:
    """The plants, every tune the arguments ask for, their report, JSON and plots (to ``plot``, named per tune
    where several run; None: no plot); the exit status."""
    steps = Steps(args.progress)
    loops = ("marlin", "klipper") if args.loop == LOOP_BOTH else (args.loop,)
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
    outcomes = [tune_one(args, problem, is_bed, client, printer, steps, plot) for problem, is_bed in problems]
    if len(outcomes) > 1:
        print("\n".join(comparison(outcomes)))
    if args.json:
        write_json(Path(args.json), outcomes[0], plant, printer, plot)
    return max(status for status, _, _ in outcomes)


def tune_one(args: argparse.Namespace, problem: Problem, is_bed: bool, client, printer: PrinterGains | None,
             steps: Steps, plot: Path | None) -> tuple[int, TuneResult, Proven | None]:
    """Tune, prove, report and plot one problem: (the exit status, tools/tuning/defaults.py; the tune; its proof)."""
    started = time.perf_counter()
    result = tune(problem, args.objective, args.method, args.budget, args.seed, client,
                  yours=printer_params(problem, printer), on_step=steps)
    for note in result.notes:
        print(f"twin-tune: {note}", file=sys.stderr)
    proof = proven(result, args.proof, cross_check_s=args.cross_check, on_step=steps) \
        if args.proof and problem.loop != "ideal" else None
    status = report(result, proof, args.proof, is_bed, printer)
    if (path := plot) is not None:
        several = args.loop == LOOP_BOTH or "," in args.controller
        suffix = f"-{problem.controller.name}-{problem.loop}" if several else ""
        path = path.with_name(f"{path.stem}{suffix}{path.suffix}")
        source = Path(args.from_log).name if args.from_log else args.plant
        title = tune_figure.title_words("bed" if is_bed else "hotend", source, result, proof)
        if several:
            title += f" ({problem.controller.name} on the {problem.loop} loop)"
        tune_figure.write(path, result, proof, title, functools.partial(describe, problem), args.plot_history)
        print(f"plot: {path}")
    if args.plot_compact:
        tab_figure.write(Path(args.plot_compact), result, proof, functools.partial(describe, problem))
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

