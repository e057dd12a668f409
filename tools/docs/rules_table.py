"""The rules table of docs/tuning.md: every preset plant tuned by every rule, run on the firmware twin.

``python -m tools.docs.rules_table`` tunes each plant of twin/plants.py (the seeds' models and the
presets fitted to real printers) with every rule of tools/tuning/rules, runs each candidate and
Marlin's own M303 C8 result through the default scenario on the Marlin firmware twin
(tools/tuning/evaluate.py), and rewrites the table between the markers in docs/tuning.md.
``--check`` compares instead (exit 1 when out of date), with the tolerances of ``same_table``.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.entry import OneLineParser, run_cli
from tools.tuning.defaults import rule_names
from tools.tuning.evaluate import Candidate, firmware_autotune, preset_problem, rule_gains, score
from tools.tuning.objectives import heater_cost, heater_terms
from twin.metrics import step_metrics
from twin.limits import UserError
from twin.plants import SPECS

DOC = Path(__file__).resolve().parents[2] / "docs" / "tuning.md"
BEGIN, END = "<!-- rules-table: begin (python -m tools.docs.rules_table) -->", "<!-- rules-table: end -->"
# Beds at 60 C (PLA); seed 000's models at its listings' setpoint, 50 C of rise, on 25 C ambient (at
# 210 C they would need 92.5 % of full power to hold, so the load step makes the target unreachable);
# every other plant at 210 C.
TARGETS_C = {"bed": 60.0, "bed_mk3": 60.0, "seed000_first": 75.0, "seed000_second": 75.0}
HOTEND_TARGET_C = 210.0
COLUMNS = ("plant", "target C", "method", "Kp", "Ki", "Kd", "rise s", "overshoot C", "settling 2% s", "IAE C s",
           "ITAE C s^2", "effort s", "trip", "heater cost", "vs M303")
# Numbers may move on another CPU: the plant's float maps differ in their last bits, which can move
# one ADC reading across a count and so shift a trajectory slightly. 2 % (or 0.05 absolute, for
# near-zero cells) covers that; verdicts ("beats", "trip", "failed") must match exactly.
REL_TOL, ABS_TOL = 0.02, 0.05


@dataclass(frozen=True)
class Row:
    plant: str
    target_c: float
    method: str
    candidate: Candidate | None
    verdict: str  # "beats" / "ties" / "loses" against M303, "reference", or why there is no run


def _cells(row: Row) -> list[str]:
    head = [row.plant, f"{row.target_c:g}", row.method]
    c = row.candidate
    if c is None:
        return head + ["-"] * (len(COLUMNS) - 4) + [row.verdict]
    run = c.run
    heat = run.t_s < run.heatup_end_s
    m = step_metrics(run.t_s[heat], run.temp_c[heat, 0], run.target_c, np.clip(run.duty[heat, 0], 0.0, 1.0))

    def num(value: float | None, digits: int = 4) -> str:
        return "-" if value is None else f"{value:.{digits}g}"

    trip = "yes" if heater_terms(run).tripped[0] else "no"
    return head + [num(c.gains.kp), num(c.gains.ki), num(c.gains.kd), num(m.rise_time_s), num(m.overshoot_c),
                   num(m.settling_time_2pct_s), num(m.iae_c_s), num(m.itae_c_s2), num(m.duty_sq_s), trip,
                   num(c.cost), row.verdict]


def cost_verdict(cost: float, reference: float) -> str:
    """Against M303: a margin of REL_TOL either way is a tie, so a verdict survives another CPU."""
    if cost < reference * (1 - REL_TOL):
        return "beats"
    return "loses" if cost > reference * (1 + REL_TOL) else "ties"


def plant_rows(preset: str) -> list[Row]:
    """M303's result and every rule's on one preset, best rule first."""
    target_c = TARGETS_C.get(preset, HOTEND_TARGET_C)
    problem = preset_problem(preset, target_c)
    rows = []
    try:
        name, gains = firmware_autotune(problem)
        reference = score(problem, heater_cost, {name: gains})[0]
        rows.append(Row(preset, target_c, name, reference, "reference"))
    except ValueError as exc:
        reference = None
        rows.append(Row(preset, target_c, "M303 C8", None, f"failed: {str(exc).split(': ', 1)[-1]}"))
    gains_by_rule, failures = rule_gains(problem, rule_names())
    failed = [Row(preset, target_c, rule, None, f"no gains: {why}") for rule, why in failures.items()]
    for c in score(problem, heater_cost, gains_by_rule) if gains_by_rule else []:
        verdict = "-" if reference is None else cost_verdict(c.cost, reference.cost)
        rows.append(Row(preset, target_c, c.method, c, verdict))
    return rows + failed


def markdown(rows: list[Row]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in _cells(row)) + " |" for row in rows]
    return "\n".join(lines)


def generate() -> str:
    rows = [row for preset in SPECS for row in plant_rows(preset)]
    return markdown(rows)


def table_of(doc: str) -> str:
    """The generated table inside a document (ValueError without the markers)."""
    match = re.search(re.escape(BEGIN) + r"\n(.*?)" + re.escape(END), doc, re.S)
    if match is None:
        raise UserError("docs/tuning.md lacks the rules-table markers")
    return match.group(1).rstrip("\n")


def _number(cell: str) -> float | None:
    try:
        return float(cell)
    except ValueError:
        return None


def same_table(a: str, b: str) -> list[str]:
    """Differences between two generated tables: numbers beyond the tolerance, any other cell exactly."""
    rows_a, rows_b = a.splitlines(), b.splitlines()
    if len(rows_a) != len(rows_b):
        return [f"{len(rows_a)} rows against {len(rows_b)}"]
    problems = []
    for line_a, line_b in zip(rows_a, rows_b, strict=True):
        cells_a, cells_b = line_a.split("|"), line_b.split("|")
        if len(cells_a) != len(cells_b):
            problems.append(f"{line_a} has {len(cells_a)} cells against {len(cells_b)}")
            continue
        for col, (x, y) in enumerate(zip(cells_a, cells_b, strict=True)):
            fx, fy = _number(x.strip()), _number(y.strip())
            same = (np.isclose(fx, fy, rtol=REL_TOL, atol=ABS_TOL) if fx is not None and fy is not None
                    else x.strip() == y.strip())
            if not same:
                problems.append(f"{cells_a[1].strip()} {cells_a[3].strip()}: column "
                                f"{COLUMNS[col - 1] if 0 < col <= len(COLUMNS) else col}: {x.strip()} != {y.strip()}")
    return problems


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.rules_table", description=__doc__.splitlines()[0],
                           epilog="exit status: 0 written (or current), 1 --check: out of date, 2 bad input")
    parser.add_argument("--check", action="store_true", help="compare with docs/tuning.md instead of writing it")
    return parser


def run(args: argparse.Namespace) -> int:
    table = generate()
    doc = DOC.read_text()
    if args.check:
        problems = same_table(table_of(doc), table)
        print("\n".join(problems) or "docs/tuning.md is current")
        return 1 if problems else 0
    start, end = doc.index(BEGIN) + len(BEGIN), doc.index(END)
    DOC.write_text(doc[:start] + "\n" + table + "\n" + doc[end:])
    print(f"wrote the rules table ({table.count(chr(10)) - 1} rows) into {DOC}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
