"""docs/tuning.md's Klipper/Kalico table (tools/docs/kalico_table.py): its pieces on a short scenario (the whole
run tunes on two plants' ensembles and is not run here), and the committed section's shape."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tools.docs.kalico_table import BEGIN, COMMAND, END, IN_SAMPLE, Row, entries, markdown, proven_rows
from tools.tuning.evaluate import score
from tools.tuning.defaults import DEFAULT_OBJECTIVE
from tools.tuning.objectives import objective
from tools.tuning.problems import build_problem, preset_source
from tools.tuning.proof import prove
from twin.scenario import Event

DOC = Path(__file__).resolve().parents[3] / "docs" / "tuning.md"
YOURS = np.array([22.2, 1.08, 114.0])
SEEDS = 2
BY = ["Klipper PID_CALIBRATE", "Kalico PID_CALIBRATE", "Kalico MPC_CALIBRATE", "the printer's gains",
      "the printer's gains"]


@pytest.fixture(scope="module")
def table():
    """hotend_cartridge (where both PID_CALIBRATEs trip verify_heater), its nominal plant, 300 s with a fan kick;
    the tunes by the rules alone (Kalico's MPC has none: twin-tune keeps MPC_CALIBRATE's)."""
    problem = build_problem(preset_source("hotend_cartridge", 0.0), loop="klipper")
    problem = replace(problem, scenario=replace(problem.scenario, duration_s=300.0,
                                                events=(Event(200.0, "fan", None, 1.0),)))
    found = entries(problem, YOURS, method="rules", seeds=SEEDS)
    return problem, found, proven_rows(found, SEEDS)


@pytest.mark.slow  # the table fixture: 14 s of CPU
def test_the_rows_are_each_autotune_the_printers_gains_and_twin_tunes_answer_on_each_loop(table):
    _, found, rows = table
    assert [e.by for e in found[:5]] == BY
    assert [(e.problem.loop, e.problem.controller.name) for e in found] == [
        ("klipper", "pid"), ("kalico", "pid"), ("kalico", "kalico_mpc"), ("klipper", "pid"), ("kalico", "pid"),
        ("klipper", "pid"), ("kalico", "pid"), ("kalico", "kalico_mpc")]
    assert all(e.by.startswith("twin-tune: ") for e in found[5:])
    assert found[7].by == "twin-tune: keep MPC_CALIBRATE" and np.array_equal(found[7].params, found[2].params)
    assert len({id(e.problem.ensemble) for e in found}) == 1  # one ensemble for every row
    for failed in rows[:2]:  # verify_heater shuts the printer down during either relay test
        assert not isinstance(failed, Row) and failed.params is None
        assert failed.failed == "PID_CALIBRATE failed on hotend_cartridge: Heater extruder not heating at expected rate"
    assert all(isinstance(row, Row) and row.runs == SEEDS for row in rows[2:])


@pytest.mark.slow  # the table fixture: 14 s of CPU
def test_a_row_is_its_entry_proven_alone(table):
    """The proof of a loop's rows together gives each row what proving it alone gives."""
    problem, found, rows = table
    alone = prove(problem, score(problem, objective(DEFAULT_OBJECTIVE), {"yours": YOURS}), SEEDS)[0]
    row = rows[3]
    assert isinstance(row, Row) and row.entry.by == "the printer's gains" and row.entry.problem.loop == "klipper"
    assert (row.trips, row.overshoot_c, row.hold_error_c, row.chatter, row.cost_s) == \
        (alone.trips, alone.overshoot_c[1], alone.hold_error_c[1], alone.chatter[0], alone.cost_s[0])


@pytest.mark.slow  # the table fixture: 14 s of CPU
def test_the_markdown_has_a_row_per_entry_and_says_in_sample(table):
    problem, _, rows = table
    text = markdown([("capture", IN_SAMPLE, problem, rows)], 90, 120, SEEDS)
    lines = [line for line in text.splitlines() if line.startswith("| capture |")]
    assert len(lines) == len(rows) and all(line.split(" | ")[1] == IN_SAMPLE for line in lines)
    assert lines[0].endswith("| - | - | - | - | - | fails: PID_CALIBRATE failed on hotend_cartridge: Heater extruder "
                             "not heating at expected rate |")
    assert "| kalico MPC | Kalico MPC_CALIBRATE | 0 of 2 |" in lines[2] and "block_heat_capacity" in lines[2]
    assert text.startswith(f"Written by `{COMMAND}`")


def test_the_committed_section_has_both_plants_and_every_row():
    text = DOC.read_text()
    section = text[text.index(BEGIN):text.index(END)]
    rows = [line.split(" | ") for line in section.splitlines() if line.startswith("| ") and "---" not in line
            and not line.startswith("| plant |")]
    plants = {row[0][2:] for row in rows}
    assert plants == {"hotend_cartridge", "klippy_stats_pdegrazia_kingroon_kp3s_a"}
    for plant in plants:
        mine = [row for row in rows if row[0][2:] == plant]
        assert {row[1] for row in mine} == {"preset" if plant == "hotend_cartridge" else IN_SAMPLE}
        assert [row[3] for row in mine[:3]] == BY[:3]
        assert sum(row[3].startswith("twin-tune: ") for row in mine) == 3
