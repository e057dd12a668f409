"""docs/tuning.md's tune-from-log section (tools/docs/fromlog.py) keeps its own rule: where it says new gains,
the answer never trips and is within the bounds on every plant (hold at most yours x 1.1 + 0.02 C, overshoot
at most yours + 0.5 C); where it says keep your gains, some plant or the ensemble's objective says why, or
no plant the log allows (every structure named with its reason); at most 2 heaters not tuned. The
run itself is python -m tools.docs.fromlog --doc docs/tuning.md (tens of minutes: not in the tests)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tools.docs.fromlog import BEGIN, COMMAND, END, Case, markdown, run_case
from tools.tuning.answer import CANNOT_MODEL
from tools.tuning.verdict import HOLD_FACTOR, HOLD_SLACK_C, OVERSHOOT_SLACK_C

DOC = Path(__file__).resolve().parents[3] / "docs" / "tuning.md"
CASE = re.compile(r"^\*\*(`[^`]+`[^*]*)\*\*: (.*)$", re.M)
ROW = re.compile(r"^\| ([^|]+) \| ([^|]+) \| (\d+|-) / (\d+) \| ([\d.]+) / ([\d.]+) \| ([\d.]+) / ([\d.]+) \| "
                 r"[^|]+ \| ([^|]+) \|$")


def _cases() -> list[tuple[str, str, list[tuple[str, ...]]]]:
    text = DOC.read_text()
    section = text[text.index(BEGIN):text.index(END)]
    assert f"Written by `{COMMAND}`" in section
    found = []
    for block in section.split("\n\n**")[1:]:
        head = CASE.match("**" + block)
        assert head is not None, block[:200]
        found.append((head.group(1), head.group(2), [m.groups() for line in block.splitlines()
                                                     if (m := ROW.match(line))]))
    return found


def test_every_new_answer_is_within_the_bounds_on_every_plant_and_every_keep_says_why():
    cases = _cases()
    assert len(cases) >= 20  # the M303 captures, the klippy logs' heaters, the PID_CALIBRATE entries
    assert sum("not tuned:" in text for _, text, _ in cases) <= 2  # a verdict wherever the gains are known
    for label, text, rows in cases:
        if "not tuned:" in text:  # a log that cannot be fitted at all
            assert not rows, label
            continue
        if text.startswith("Answer: **keep your gains** (") and not rows:  # no plant the log allows: why
            assert f"{CANNOT_MODEL}: no plant both fits it and replays it: " in text, label
            continue
        assert rows, label
        if "**new gains**" in text:
            for plant, _, trips, _, hold, hold_yours, over, over_yours, within in rows:
                assert trips == "0" and within.strip() == "yes", (label, plant)
                assert float(hold) <= float(hold_yours) * HOLD_FACTOR + HOLD_SLACK_C + 0.005, (label, plant)
                assert float(over) <= float(over_yours) + OVERSHOOT_SLACK_C + 0.005, (label, plant)
        else:
            assert "**keep your gains**" in text, label
            assert "not 5% below" in text or any(r[-1].strip() != "yes" for r in rows), label


@pytest.mark.slow
def test_a_capture_no_plant_replays_is_answered_keep_your_gains(hardware_logs):
    """Before, "not tuned: ... no plant both fits it and replays it" though it parsed and states its gains."""
    outcome = run_case(Case(hardware_logs / "m303_hotend_S250_trace_marlin8081_partial.txt", "extruder"), budget=90)
    assert outcome.kept and outcome.proof is None
    assert outcome.text.startswith("Answer: **keep your gains** (Kp 15.65 Ki 1.42 Kd 42.96: the last Kp/Ki/Kd the "
                                   f"capture printed): {CANNOT_MODEL}: no plant both fits it and replays it: fopdt: ")
    assert "1 heaters: new gains on 0, keep your gains on 1, not tuned on 0." in markdown([outcome], 90)
