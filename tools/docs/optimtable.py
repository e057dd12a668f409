"""The optimisers' table of docs/tuning.md: DE, PSO and OCALO against the best rule and M303.

The claim checked: on ``hotend_cartridge`` and on plants fitted from the captured hardware
logs, a search on the firmware twin finds gains at least as good as the best classical rule on the
heater objective, and better than the firmware's own autotune (Marlin M303 C8). Each plant is
built as twin-tune builds it (a preset, or ``--from-log`` fitted as twin-fit does), nominal and
noiseless; each optimiser searches 0 .. 4 x the best rule's gains (twin-tune centres that box on the
autotune's gains instead; here the box must not start from the reference it is compared with), cold
(no warm start), with a fixed seed and budget.

``python -m tools.docs.optimtable`` rewrites the section between the markers in docs/tuning.md;
``--budget`` and ``--plants`` give a reduced run (the test's).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from tools.docs.rules_table import cost_verdict
from tools.cli.args import doc_page
from tools.entry import OneLineParser, run_cli
from tools.ident.log_fit import LogFitOptions
from tools.logs import hardware_logs_dir
from tools.tuning.defaults import rule_names
from tools.tuning.evaluate import Candidate, rule_gains, score
from tools.tuning.objectives import heater_cost
from tools.tuning.evaluate import Problem
from tools.tuning.problems import build_problem, log_source, preset_source
from tools.tuning.tuner import optimise, references, search_bounds
from twin.plants import SPECS
from twin.limits import UserError

DOC = Path(__file__).resolve().parents[2] / "docs" / "tuning.md"
BEGIN, END = "<!-- optim-table: begin", "<!-- optim-table: end -->"
OPTIMISERS = ("de", "pso", "ocalo")
BUDGET = 900  # evaluations per optimiser: twin-tune's default (20 generations of DE's 45)
SEED = 0
# (label, plant): the presets fitted to logs, then two printers' Klipper Stats logs fitted as twin-fit
# fits them (tools/ident/log_fit.py: two-node model, the default segment), the extruder's.
PLANTS: dict[str, str] = {
    "hotend_cartridge": "hotend_cartridge",
    "bed": "bed",
    "ender5 extruder": "klippy_stats_icodextrin_ender5_creality427.csv",
    "kp3s extruder": "klippy_stats_pdegrazia_kingroon_kp3s_a.csv",
}


@dataclass(frozen=True)
class PlantResult:
    """One plant: the best rule, M303 and each optimiser, scored on the heater objective."""

    plant: str
    source: str
    best_rule: Candidate
    m303: Candidate | None
    optimised: dict[str, Candidate]

    def verdicts(self, method: str) -> tuple[str, str]:
        """(against the best rule, against M303): beats / ties / loses, with rules_table.py's tie margin."""
        cost = self.optimised[method].cost
        vs_m303 = "-" if self.m303 is None else cost_verdict(cost, self.m303.cost)
        return cost_verdict(cost, self.best_rule.cost), vs_m303

    def accepted(self, method: str) -> bool:
        """At least as good as the best rule, and better than M303."""
        vs_rule, vs_m303 = self.verdicts(method)
        return vs_rule != "loses" and vs_m303 == "beats"


def problem_of(label: str) -> Problem:
    """The plant as twin-tune builds it, on its nominal model with a noiseless sensor: this table compares
    optimisers, not robustness (docs/tuning.md's robust tuning section does that)."""
    plant = PLANTS[label]
    source = preset_source(plant, spread=0.0) if plant in SPECS else \
        log_source(hardware_logs_dir() / plant, LogFitOptions(heater="extruder"))
    return build_problem(source, noise_lsb=0.0, spread=False)


def run_plant(label: str, budget: int, seed: int, methods: tuple[str, ...] = OPTIMISERS) -> PlantResult:
    problem = problem_of(label)
    refs, _ = references(problem, heater_cost)
    gains, _ = rule_gains(problem, rule_names())
    best_rule = score(problem, heater_cost, gains)[0]
    box = search_bounds(problem, best_rule.params)
    optimised = {m: optimise(problem, heater_cost, m, box, budget, seed) for m in methods}
    m303 = next((r for r in refs if r.method.startswith("M303")), None)
    return PlantResult(label, problem.name, best_rule, m303, optimised)


def _g(value: float) -> str:
    return f"{value:.4g}"


def markdown(results: list[PlantResult], budget: int, seed: int) -> str:
    methods = list(results[0].optimised)
    head = ["plant", "best rule", "rule cost", "M303 cost"]
    head += [f"{m.upper()} cost (vs rule / vs M303)" for m in methods] + ["accepted"]
    lines = [f"Budget {budget} evaluations per optimiser, seed {seed}, heater objective, Marlin firmware twin; "
             "ties are within 2 % (tools/docs/rules_table.py REL_TOL).", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        cells = [f"{r.plant} ({r.source})", r.best_rule.method, _g(r.best_rule.cost),
                 "failed" if r.m303 is None else _g(r.m303.cost)]
        cells += [f"{_g(r.optimised[m].cost)} ({' / '.join(r.verdicts(m))})" for m in methods]
        cells.append(", ".join(m for m in methods if r.accepted(m)) or "none")
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    passed = sum(all(r.accepted(m) for m in methods) for r in results)
    lines += ["", f"Every optimiser accepted on {passed} of {len(results)} plants."]
    return "\n".join(lines) + "\n"


def write_doc(path: Path, body: str, command: str) -> None:
    from tools.validation.doc_compare import write_section

    write_section(path, f"Written by `{command}`.\n\n{body}", BEGIN, END)


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.optimtable", description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=BUDGET, help="evaluations per optimiser, at least 150 "
                        "(OCALO: 3 x its population of 50) (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=SEED, help="every optimiser's seed (default: %(default)s)")
    parser.add_argument("--plants", default=",".join(PLANTS),
                        help="comma-separated plant labels, of " + ", ".join(PLANTS) + " (default: all)")
    parser.add_argument("--doc", type=doc_page(BEGIN, END), help="rewrite the optimiser section of this file (docs/tuning.md)")
    return parser


def run(args: argparse.Namespace, argv: list[str]) -> int:
    labels = args.plants.split(",")
    unknown = [p for p in labels if p not in PLANTS]
    if unknown:
        raise UserError(f"--plants: unknown {unknown}, choose from {list(PLANTS)}")
    if args.budget < 150:
        raise UserError("--budget must be >= 150 (OCALO: 3 x its population of 50)")
    table = markdown([run_plant(p, args.budget, args.seed) for p in labels], args.budget, args.seed)
    if args.doc is not None:
        write_doc(args.doc, table, ("python -m tools.docs.optimtable " + " ".join(argv)).strip())
    print(table, end="")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), lambda args: run(args, sys.argv[1:] if argv is None else argv), argv)


if __name__ == "__main__":
    sys.exit(main())
