"""What the tab says for each of twin-tune's exit codes (octoprint_heater_twin/tuner.py ``outcome``): an answer, or
a message that names what happened, never a bare status, and a bug never dressed as the user's capture. The tuner
module runs twin-tune as a process and reads its status; the plugin's package imports OctoPrint, so it needs the
``octoprint`` extra."""

from __future__ import annotations

import json

import pytest

from tests.helpers.octoprint_server import require_octoprint

require_octoprint()

from octoprint_heater_twin import tuner  # noqa: E402  (OctoPrint first: the package imports it)
from octoprint_heater_twin.tuner import NO_MATPLOTLIB, outcome  # noqa: E402
from tools import entry  # noqa: E402
from tools.tuning import defaults  # noqa: E402
from tools.tuning.defaults import EXIT_ANSWER, EXIT_NO_MODEL, EXIT_UNSAFE  # noqa: E402
from tools.entry import EXIT_INTERNAL, EXIT_USAGE  # noqa: E402


def test_an_answer_is_the_json_and_says_why_it_has_no_plot(tmp_path):
    path = tmp_path / "answer.json"
    path.write_text(json.dumps({"verdict": "keep your gains", "answer": None, "target_c": None}))
    got = outcome(EXIT_ANSWER, "", path, plot=False)
    assert got.answer == {"verdict": "keep your gains", "answer": None, "target_c": None}
    assert got.error is None and got.no_plot == NO_MATPLOTLIB


def test_an_unreadable_answer_is_said(tmp_path):
    got = outcome(EXIT_ANSWER, "", tmp_path / "missing.json", plot=True)
    assert got.answer is None and "unreadable" in str(got.error)


@pytest.mark.parametrize("status, words", [
    (EXIT_UNSAFE, "No safe answer"),
    (EXIT_USAGE, "cannot use this capture"),
    (EXIT_NO_MODEL, "printer's gains are not known"),
    (EXIT_INTERNAL, "internal error (a bug, not your capture)"),
    (9, "stopped with status 9"),
])
def test_each_failure_is_named_before_twin_tunes_own_line(tmp_path, status, words):
    last = "twin-tune: error: something it said"
    got = outcome(status, last, tmp_path / "answer.json", plot=True)
    assert got.answer is None
    assert words in str(got.error) and str(got.error).endswith(last)
    alone = str(outcome(status, "", tmp_path / "answer.json", plot=True).error)  # no line of its own: the message
    assert words in alone and not alone.endswith(":")


def test_the_plugins_codes_are_twin_tunes():
    assert (tuner.EXIT_ANSWER, tuner.EXIT_UNSAFE, tuner.EXIT_NO_MODEL) == \
        (defaults.EXIT_ANSWER, defaults.EXIT_UNSAFE, defaults.EXIT_NO_MODEL)
    assert (tuner.EXIT_USAGE, tuner.EXIT_INTERNAL) == (entry.EXIT_USAGE, entry.EXIT_INTERNAL)
