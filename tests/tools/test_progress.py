"""tools/progress.py: the step lines a program reads stay as they were, and the whole run is one fraction that
never goes back, in a user's words, with a time left once the fraction says enough."""

from __future__ import annotations

import re

import pytest

from tools.progress import MIN_ESTIMATE_FRACTION, STAGES, RunProgress, Steps, words

RUN_RE = re.compile(r"^run: (\d+)%(?: about (\d+) s left)?: (.+)$")


class Clock:
    def __init__(self):
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def test_the_shares_cover_a_run_and_every_step_has_a_users_words():
    assert sum(s.share for s in STAGES) == pytest.approx(1.0)
    assert words("searching (de)") == "Searching for better gains"
    assert words("fitting the structures") == words("profiling what the log leaves open")
    assert words("something new") == "something new"  # a step the table does not know, as it is named


def test_the_lines_keep_the_step_and_add_the_run_in_a_users_words(capsys):
    clock = Clock()
    steps = Steps("lines", clock)
    advance = steps("fitting the structures", 2)
    clock.now_s += 10.0
    advance()
    advance()
    clock.now_s += 10.0
    steps("searching (de)", 4)(4)
    err = capsys.readouterr().err.splitlines()
    assert [line for line in err if line.startswith("progress: ")] == [
        "progress: fitting the structures 1/2", "progress: fitting the structures 2/2", "progress: searching (de) 4/4"]
    runs = [RUN_RE.match(line) for line in err if line.startswith("run: ")]
    assert all(runs) and len(runs) == 5  # at each step's start and after each advance
    percents = [int(m[1]) for m in runs]
    assert percents == sorted(percents) and percents[0] == 0
    assert runs[0][3] == "Learning your heater from the capture" and runs[-1][3] == "Searching for better gains"
    assert runs[0][2] is None  # nothing done: no estimate
    # after fitting (0.15 of the run) and searching (0.48, all but proving's 0.10 and the steps between): 20 s
    # so far for 78 % done
    fraction = (0.15 + 0.07 + 0.04 + 0.16 + 0.48) / 1.0
    assert int(runs[-1][1]) == round(100 * fraction)
    assert int(runs[-1][2]) == round(20.0 * (1 - fraction) / fraction)


def test_the_run_never_goes_back_and_an_unknown_step_keeps_it():
    run = RunProgress(Clock())
    run.update("searching (de)", 450, 900)
    half = run.fraction
    run.update("searching (nm)", 0, 900)  # a second optimiser: the same stage again
    run.update("what a new tuner calls its step", 1, 2)
    assert run.fraction == half


def test_a_preset_starts_the_run_at_the_rules():
    run = RunProgress(Clock())
    run.update("the firmware's autotune, the references and the rules", 0, 2)
    assert run.fraction == 0.0 and run.left_s() is None
    run.update("proving", 5, 5)
    assert run.fraction == pytest.approx(1.0)


def test_no_estimate_before_the_fraction_says_enough():
    clock = Clock()
    run = RunProgress(clock)
    run.update("fitting the structures", 1, 10)  # 1.5 % of the run
    clock.now_s += 5.0
    assert run.fraction < MIN_ESTIMATE_FRACTION and run.left_s() is None and run.estimate() == "2%"
    run.update("fitting the structures", 10, 10)
    assert run.left_s() == pytest.approx(5.0 * 0.85 / 0.15)
    assert run.estimate() == "15%, about 28 s left"


def test_the_bar_mode_is_quiet_off_a_terminal(capsys):
    Steps("bar", Clock())("proving", 2)(2)
    assert capsys.readouterr().err == ""
