"""The optimisers' table: a reduced run's verdicts, the doc's verdicts against its own numbers, bad flags."""

from __future__ import annotations

import re

import pytest

from tools.docs import optimtable
from tools.validation.doc_compare import replace_section
from tools.docs.rules_table import REL_TOL, cost_verdict

# The full table (900 evaluations per optimiser, four plants) takes minutes; the test runs the
# reduced configuration: hotend_cartridge, 300 evaluations, seed 0.
REDUCED_PLANT, REDUCED_BUDGET = "hotend_cartridge", 300


@pytest.fixture(scope="module")
def reduced() -> optimtable.PlantResult:
    return optimtable.run_plant(REDUCED_PLANT, REDUCED_BUDGET, seed=0)


@pytest.mark.slow


def test_reduced_run_beats_m303_and_matches_the_best_rule(reduced) -> None:
    assert reduced.m303 is not None
    for method in optimtable.OPTIMISERS:
        vs_rule, vs_m303 = reduced.verdicts(method)
        assert vs_rule in ("beats", "ties"), (method, reduced.optimised[method].cost, reduced.best_rule.cost)
        assert vs_m303 == "beats", (method, reduced.optimised[method].cost, reduced.m303.cost)
        assert reduced.accepted(method)


@pytest.mark.slow  # the module's reduced run: about 6 s
def test_optimiser_gains_reproduce_their_cost(reduced) -> None:
    """The stated cost is the cost of the stated gains: rescoring them gives it back (same machine)."""
    from tools.tuning.evaluate import score
    from tools.tuning.objectives import heater_cost

    problem = optimtable.problem_of(REDUCED_PLANT)
    for method, candidate in reduced.optimised.items():
        again = score(problem, heater_cost, {method: candidate.gains})[0]
        assert again.cost == pytest.approx(candidate.cost, rel=1e-9)


def _doc_rows() -> list[list[str]]:
    doc = optimtable.DOC.read_text()
    section = doc[doc.index(optimtable.BEGIN): doc.index(optimtable.END)]
    rows = [line.split("|")[1:-1] for line in section.splitlines() if line.startswith("| ") and "---" not in line]
    return [[c.strip() for c in row] for row in rows[1:]]


def test_doc_verdicts_follow_from_its_numbers() -> None:
    """Each verdict in docs/tuning.md's optimiser table is what its printed costs give (4 digits
    printed, so a cost within 0.05 % of a tie boundary could flip: none is that close here)."""
    rows = _doc_rows()
    assert len(rows) == len(optimtable.PLANTS)
    for row in rows:
        rule_cost, m303_cost = float(row[2]), float(row[3])
        for cell in row[4:-1]:
            cost, vs_rule, vs_m303 = re.fullmatch(r"(\S+) \((\w+) / (\w+)\)", cell).groups()
            assert vs_rule == cost_verdict(float(cost), rule_cost)
            assert vs_m303 == cost_verdict(float(cost), m303_cost)
            assert abs(float(cost) / m303_cost - (1 - REL_TOL)) > 5e-4


def test_replace_section_keeps_the_markers_and_the_rest() -> None:
    text = "a\n<!-- x: begin (cmd) -->\nold\n<!-- x: end -->\nb\n"
    assert replace_section(text, "new\n", "<!-- x: begin", "<!-- x: end -->") == (
        "a\n<!-- x: begin (cmd) -->\nnew\n<!-- x: end -->\nb\n")
    assert replace_section("no markers", "new", "<!-- x: begin", "<!-- x: end -->") is None


@pytest.mark.parametrize("argv, flag", [(["--plants", "nope"], "--plants"), (["--budget", "10"], "--budget")])
def test_bad_flags_one_line(argv, flag, capsys) -> None:
    assert optimtable.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and flag in err


def test_benchfuncs_doc_rewrites_only_its_section(tmp_path) -> None:
    """benchfuncs --doc (the F1-F23 section of docs/tuning.md) uses the same section writer."""
    from tools.cli import benchfuncs

    doc = tmp_path / "tuning.md"
    doc.write_text("keep\n<!-- benchfuncs: begin (cmd) -->\nold\n<!-- benchfuncs: end -->\ntail\n")
    argv = ["--quick", "--functions", "F1,F6", "--methods", "alo,ocalo", "--workers", "1", "--doc", str(doc)]
    assert benchfuncs.main(argv) == 0
    text = doc.read_text()
    assert text.startswith("keep\n<!-- benchfuncs: begin (cmd) -->\nWritten by `python -m tools.cli.benchfuncs --quick")
    assert text.endswith("<!-- benchfuncs: end -->\ntail\n") and "\nold\n" not in text and "OCALO beats ALO on" in text
    assert benchfuncs.main(["--quick", "--doc", str(tmp_path / "missing.md")]) == 2
