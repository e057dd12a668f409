"""Cross-validation on real data: gains tuned on the plant fitted to one log of a printer, scored on the
plants fitted to its other logs.

For every printer with several captures of one heater in hardware_logs (``GROUPS``), each log is
fitted as twin-fit fits it and tuned as ``twin-tune --from-log LOG`` tunes it (the fit's ensemble,
its reading noise, the robust statistic; DE with ``BUDGET`` evaluations from the best rule, no
proof); the answer is then scored on every other log's problem. The table gives, per (tuned on,
scored on) pair, the cost of those gains there, the cost of that log's own tune there, and the loss
(the difference: what tuning on the other log cost). In-sample rows (scored on its own fit) are
marked so. ``python -m tools.docs.crossval --doc docs/tuning.md`` rewrites its section.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np

from tools.ident.log_fit import LogFitOptions
from tools.logs import hardware_logs_dir
from tools.tuning.evaluate import Problem, score
from tools.tuning.defaults import DEFAULT_OBJECTIVE
from tools.tuning.objectives import objective
from tools.tuning.problems import build_problem, log_source
from tools.tuning.tuner import tune
from tools.validation.doc_compare import publish_section
from tools.cli.args import doc_page
from tools.entry import OneLineParser, run_cli

BEGIN, END = "<!-- crossval: begin", "<!-- crossval: end -->"
COMMAND = "python -m tools.docs.crossval --doc docs/tuning.md"
BUDGET = 270  # DE: six generations of 45
SEED = 0
TARGET_C = 210.0
# printer -> (heater, its captures): one heater's logs of one printer
GROUPS: dict[str, tuple[str, tuple[str, ...]]] = {
    "onionheater hotend (Klipper heattests)": ("extruder", (
        "klipper_heattest_onionheater_heattest_200.csv", "klipper_heattest_onionheater_heattest_fan_200.csv",
        "klipper_heattest_onionheater_heattest_fan_200_2.csv", "klipper_heattest_onionheater_sample_trace.csv")),
    "Kingroon KP3S extruder (Klipper Stats)": ("extruder", (
        "klippy_stats_pdegrazia_kingroon_kp3s_a.csv", "klippy_stats_pdegrazia_kingroon_kp3s_b.csv")),
}


@dataclass(frozen=True)
class Cell:
    tuned_on: str
    scored_on: str
    cost: float  # the tuned-on log's answer on the scored-on log's problem
    own_cost: float  # the scored-on log's own answer there

    @property
    def loss(self) -> float:
        return self.cost - self.own_cost


def problem_of(name: str, heater: str) -> Problem:
    return build_problem(log_source(hardware_logs_dir() / name, LogFitOptions(heater=heater)), TARGET_C)


def group_cells(heater: str, names: tuple[str, ...], budget: int = BUDGET, seed: int = SEED) -> list[Cell]:
    """Every (tuned on, scored on) pair of one printer's logs."""
    problems = {name: problem_of(name, heater) for name in names}
    answers = {name: tune(p, DEFAULT_OBJECTIVE, "auto", budget, seed).best.params for name, p in problems.items()}
    cost = objective(DEFAULT_OBJECTIVE)
    cells = []
    for scored_on, problem in problems.items():
        scored = {c.method: c.cost for c in score(problem, cost, dict(answers))}
        cells += [Cell(tuned_on, scored_on, scored[tuned_on], scored[scored_on]) for tuned_on in names]
    return cells


def _short(name: str) -> str:
    return name.rsplit(".", 1)[0].replace("klipper_heattest_onionheater_", "").replace(
        "klippy_stats_pdegrazia_kingroon_", "")


def markdown(groups: dict[str, list[Cell]], budget: int) -> str:
    lines = [f"Written by `{COMMAND}`: each log fitted and tuned as `twin-tune --from-log LOG` does (its fit's "
             f"ensemble and reading noise, cost = the robust statistic of the {DEFAULT_OBJECTIVE} objective; DE, "
             f"{budget} evaluations, seed {SEED}, no proof), at {TARGET_C:g} C. Loss: the cost of the gains tuned on "
             "the other log minus the cost of the log's own tune, on the log scored (0 on the in-sample rows).", ""]
    for printer, cells in groups.items():
        lines += [f"**{printer}**", "", "| tuned on | scored on | sample | cost | own tune's cost | loss |",
                  "|---|---|---|---|---|---|"]
        for c in cells:
            sample = "in-sample" if c.tuned_on == c.scored_on else "out-of-sample"
            lines.append(f"| {_short(c.tuned_on)} | {_short(c.scored_on)} | {sample} | {c.cost:.4g} | "
                         f"{c.own_cost:.4g} | {c.loss:+.4g} |")
        out = [c.loss for c in cells if c.tuned_on != c.scored_on]
        lines += ["", f"Out of sample: mean loss {np.mean(out):+.4g}, worst {max(out):+.4g} "
                      f"({len(out)} pairs).", ""]
    return "\n".join(lines)


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.crossval", description=__doc__.splitlines()[0])
    parser.add_argument("--doc", type=doc_page(BEGIN, END), help="rewrite the section of this file (docs/tuning.md)")
    parser.add_argument("--budget", type=int, default=BUDGET, help="DE evaluations per tune (default: %(default)s)")
    return parser


def run(args: argparse.Namespace) -> int:
    groups = {printer: group_cells(heater, names, args.budget) for printer, (heater, names) in GROUPS.items()}
    body = markdown(groups, args.budget)
    return publish_section(body, args.doc, BEGIN, END)


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
