"""Klipper's and Kalico's autotunes beside the twin's robust tune, proven on the same plants: the table in
docs/tuning.md.

For each plant (``PLANTS``: the hotend_cartridge preset, and a Klipper Stats capture fitted as
``twin-tune --from-log`` fits it), on the ensemble twin-tune builds for it (a preset's corners, or every plant
the log allows, with the log's reading noise), at its default target:

- Klipper's PID_CALIBRATE on the klipper loop; Kalico's PID_CALIBRATE and MPC_CALIBRATE on the kalico loop
  (tools/tuning/evaluate.py ``firmware_autotune``: each on the nominal plant's twin, as a user runs it);
- a capture's own gains (the printer's, from the log's config dump) on both loops;
- the twin's robust tune on each loop: twin-tune's answer (tools/tuning/tuner.py ``tune`` then ``proven``: new
  parameters, or the ones it says to keep) for the PID on the klipper and kalico loops and for Kalico's MPC;

then every row proven with tools/tuning/proof.py ``prove`` on every member over ``PROOF_SEEDS`` noise seeds,
all rows of a plant on the same ensemble. A capture's rows are in-sample: its plants are fitted to the log
whose printer the rows are judged on. ``python -m tools.docs.kalico_table --doc docs/tuning.md`` rewrites its
section (not run in CI: the MPC rows run one KlipperTwin per candidate).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace

import numpy as np

from firmware_port.firmwares import KALICO_MPC, param_space
from tools.cli.args import doc_page, ranged_int
from tools.cli.tune import BUDGET_MAX
from tools.entry import OneLineParser, run_cli
from tools.ident.log_fit import LogFitOptions
from tools.logs import hardware_logs_dir
from tools.tuning.evaluate import Problem, firmware_autotune, score
from tools.tuning.gains import Gains
from tools.tuning.defaults import DEFAULT_OBJECTIVE
from tools.tuning.objectives import objective
from tools.tuning.problems import Source, build_problem, log_source, preset_source
from tools.tuning.proof import PROOF_SEEDS, prove
from tools.tuning.tuner import DEFAULT_BUDGET, tune
from tools.tuning.tuner import proven as proven_tune
from tools.tuning.verdict import ensemble_cost
from tools.validation.doc_compare import publish_section

BEGIN, END = "<!-- kalico-table: begin", "<!-- kalico-table: end -->"
COMMAND = "python -m tools.docs.kalico_table --doc docs/tuning.md"
PRESET = "hotend_cartridge"
CAPTURE = "klippy_stats_pdegrazia_kingroon_kp3s_a.csv"  # Kingroon KP3S extruder, Klipper Stats with its config
MPC_BUDGET = 240  # DE on Kalico's MPC: four generations of 60; its candidates run one KlipperTwin each
SEED = 0
IN_SAMPLE, PRESET_SAMPLE = "in-sample", "preset"


@dataclass(frozen=True)
class Entry:
    """One row before its proof: who gave the parameters, the problem (loop, controller) they run on, the
    parameters, or why there are none."""

    by: str
    problem: Problem
    params: np.ndarray | None
    failed: str = ""


@dataclass(frozen=True)
class Row:
    """An entry proven on every member: trips of runs, the worst overshoot and hold error, the mean duty
    chatter, the heater objective over the ensemble (tools/tuning/verdict.py ``ensemble_cost``)."""

    entry: Entry
    trips: int
    runs: int
    overshoot_c: float
    hold_error_c: float
    chatter: float
    cost_s: float


def problems(klipper: Problem) -> tuple[Problem, Problem, Problem]:
    """The PID on the klipper loop (as given), the PID and Kalico's MPC on the kalico loop: one ensemble for all."""
    return klipper, replace(klipper, loop="kalico"), replace(klipper, loop="kalico", controller=param_space(KALICO_MPC))


def autotune_entry(by: str, problem: Problem) -> Entry:
    """The loop's firmware autotune of the problem's family, or why it failed."""
    try:
        return Entry(by, problem, firmware_autotune(problem)[1])
    except ValueError as exc:
        return Entry(by, problem, None, str(exc))


def tuned_entry(problem: Problem, yours: np.ndarray | None, budget: int, method: str = "auto",
                seeds: int = PROOF_SEEDS) -> Entry:
    """twin-tune's answer on the problem (``method``, ``budget``; its proof over ``seeds``): the new parameters,
    else the reference it keeps."""
    proof = proven_tune(tune(problem, DEFAULT_OBJECTIVE, method, budget, SEED, yours=yours), seeds)
    if proof.answer is not None:
        return Entry(f"twin-tune: new ({proof.answer.method})", problem, proof.answer.params)
    return Entry(f"twin-tune: keep {proof.yours.method}", problem, proof.yours.params)


def entries(klipper: Problem, yours: np.ndarray | None, budget: int = DEFAULT_BUDGET, mpc_budget: int = MPC_BUDGET,
            method: str = "auto", seeds: int = PROOF_SEEDS) -> list[Entry]:
    """Every row of a plant (module docstring) from its problem on the klipper loop and the printer's gains
    (None: a preset's), in the table's order; the tunes by ``method`` (twin-tune's default: auto)."""
    klipper, kalico, mpc = problems(klipper)
    mine = [] if yours is None else [Entry("the printer's gains", p, yours) for p in (klipper, kalico)]
    return [autotune_entry("Klipper PID_CALIBRATE", klipper), autotune_entry("Kalico PID_CALIBRATE", kalico),
            autotune_entry("Kalico MPC_CALIBRATE", mpc), *mine, tuned_entry(klipper, yours, budget, method, seeds),
            tuned_entry(kalico, yours, budget, method, seeds), tuned_entry(mpc, None, mpc_budget, method, seeds)]


def proven_rows(found: list[Entry], seeds: int = PROOF_SEEDS) -> list[Row | Entry]:
    """Each entry with parameters proven on every member of its problem's ensemble over ``seeds`` seeds (the
    entries of one loop and controller in one proof, their parameters as the firmware holds them), a failed
    entry as it is; in the entries' order."""
    groups: dict[tuple[str, str], dict[str, np.ndarray]] = {}  # the entries' indices (unique names) -> params
    for k, e in enumerate(found):
        if e.params is not None:
            groups.setdefault((e.problem.loop, e.problem.controller.name), {})[str(k)] = e.params
    out: list[Row | Entry] = list(found)
    cost = objective(DEFAULT_OBJECTIVE)
    for table in groups.values():
        problem = found[int(next(iter(table)))].problem
        scored = {c.method: c for c in score(problem, cost, table)}
        proof = prove(problem, [scored[n] for n in table], seeds)
        for n in table:
            k = int(n)
            rows = [r for r in proof if r.method == n]
            out[k] = Row(replace(found[k], params=scored[n].params), sum(r.trips for r in rows), sum(r.runs for r in rows),
                         max(r.overshoot_c[1] for r in rows), max(r.hold_error_c[1] for r in rows),
                         float(np.mean([r.chatter[0] for r in rows])), ensemble_cost(rows, problem.ensemble))
    return out


def row_line(plant: str, sample: str, row: Row | Entry) -> str:
    """One markdown row: the plant, in- or out-of-sample, the loop and controller, who, then the proof."""
    entry = row.entry if isinstance(row, Row) else row
    problem = entry.problem
    what = f"{problem.loop} {'PID' if problem.controller.pid else 'MPC'}"
    head = f"| {plant} | {sample} | {what} | {entry.by} |"
    if not isinstance(row, Row):
        return f"{head} - | - | - | - | - | fails: {entry.failed} |"
    assert entry.params is not None
    params = str(Gains(*entry.params)) if problem.controller.pid else problem.controller.describe(entry.params)
    return (f"{head} {row.trips} of {row.runs} | {row.overshoot_c:.2f} | {row.hold_error_c:.3f} | {row.chatter:.4f} | "
            f"{row.cost_s:.4g} | {params} |")


def markdown(plants: list[tuple[str, str, Problem, list[Row | Entry]]], budget: int, mpc_budget: int,
             seeds: int) -> str:
    """The section: how it was made, then per plant its ensemble and rows."""
    lines = [f"Written by `{COMMAND}`: on each plant's ensemble (as twin-tune builds it), Klipper's "
             "PID_CALIBRATE on the klipper loop, Kalico's PID_CALIBRATE and MPC_CALIBRATE on the kalico loop (each "
             "on the nominal plant's twin), a capture's own gains, and twin-tune's answer on each loop (DE, "
             f"{budget} evaluations for the PID, {mpc_budget} for Kalico's MPC, seed {SEED}, against the printer's "
             "gains, else the loop's autotune, else the family's defaults), every row then proven on every member over "
             f"{seeds} noise seeds. Trips: runs that tripped of all runs; overshoot and hold |e|: the worst member "
             "and seed; chatter: mean |duty change| per reading while holding; objective: the heater objective's "
             "statistic over the members (s). A capture's rows are in-sample: its plants are fitted to that log.", ""]
    for plant, sample, problem, rows in plants:
        assert problem.ensemble is not None
        lines += [f"**{plant}** at {problem.scenario.target_c:g} C: {problem.ensemble.describe()}", "",
                  "| plant | sample | loop | by | trips | overshoot C | hold \\|e\\| C | chatter | objective | "
                  "parameters |", "|---|---|---|---|---|---|---|---|---|---|",
                  *(row_line(plant, sample, row) for row in rows), ""]
    return "\n".join(lines)


def sources() -> list[tuple[str, str, Source]]:
    """(label, sample, source) of every plant of the table."""
    capture = log_source(hardware_logs_dir() / CAPTURE, LogFitOptions(heater="extruder"))
    return [(PRESET, PRESET_SAMPLE, preset_source(PRESET)), (CAPTURE.rsplit(".", 1)[0], IN_SAMPLE, capture)]


def printer_gains(source: Source) -> np.ndarray | None:
    """The gains the source's printer runs (a log's), as (Kp, Ki, Kd); None for a preset."""
    if source.printer is None:
        return None
    gains = source.printer.gains
    return np.array([gains.kp, gains.ki, gains.kd])


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.kalico_table", description=__doc__.splitlines()[0])
    parser.add_argument("--doc", type=doc_page(BEGIN, END), help="rewrite the section of this file (docs/tuning.md)")
    parser.add_argument("--budget", type=ranged_int(1, BUDGET_MAX), default=DEFAULT_BUDGET,
                        help="DE evaluations per PID tune (default: %(default)s, twin-tune's)")
    parser.add_argument("--mpc-budget", type=ranged_int(1, BUDGET_MAX), default=MPC_BUDGET,
                        help="DE evaluations for Kalico's MPC (default: %(default)s)")
    return parser


def run(args: argparse.Namespace) -> int:
    plants = []
    for label, sample, source in sources():
        klipper = build_problem(source, loop="klipper")
        found = entries(klipper, printer_gains(source), args.budget, args.mpc_budget)
        plants.append((label, sample, klipper, proven_rows(found)))
    return publish_section(markdown(plants, args.budget, args.mpc_budget, PROOF_SEEDS), args.doc, BEGIN, END)


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
