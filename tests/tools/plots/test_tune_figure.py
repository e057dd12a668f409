"""twin-tune's figure (tools/plots/tune_figure.py), found in its artists: the trips marked where the scalar twin
says they happened (and the batch's own trace agrees), the answer and your gains first and labelled, each limit
cycle with the amplitude twin-tune's metrics print, the title in a user's words, the search's history only when
asked for, in plain numbers. One real tune: the rules on hotend_cartridge (its nominal plant, seeded), proven on
one seed, your gains given."""

from __future__ import annotations

import functools
import re

import numpy as np
import pytest

from tools.cli.tune_work import describe, metrics_line
from tools.plots import tune_figure
from tools.plots.marks import TRIP_MARKER
from tests.tools.plots.conftest import YOURS
from tools.tuning.evaluate import first_run_trips, preset_problem
from tools.tuning.tuner import tune

pytestmark = pytest.mark.slow  # the tune and its proof (conftest.py's tuned): about 5 s on a quiet machine


@pytest.fixture(scope="module")
def figure(tuned):
    result, proof = tuned
    title = tune_figure.title_words("hotend", "hotend_cartridge", result, proof)
    return tune_figure.draw(result, proof, title, functools.partial(describe, result.problem))


def _legend(fig) -> list[str]:
    return [text.get_text() for text in fig.legends[0].get_texts()]


def test_each_trip_is_where_the_batch_halted(tuned):
    """The scalar re-run's trip time is where the batch's lane halted: its heater off and its reading held from
    then on, the heater on until that reading where it was on just before; a candidate that did not trip has none."""
    result, _ = tuned
    tripped = [c for c in result.candidates if c.run.tripped[0]]
    calm = next(c for c in result.candidates if not c.run.tripped[0])
    assert tripped, "the rules trip on hotend_cartridge's nominal plant: the case this test needs"
    trips = first_run_trips(result.problem, np.array([c.params for c in [*tripped, calm]]))
    assert trips[-1] is None
    for c, (at_s, reason) in zip(tripped, trips):
        t_s, duty, temp = c.run.t_s, c.run.duty[:, 0], c.run.temp_c[:, 0]
        after = t_s >= at_s
        assert reason == "Thermal Runaway"
        assert after.any() and not after.all()
        assert np.all(duty[after] == 0) and np.ptp(temp[after]) == 0, c.method
        if duty[~after][-1] > 0:
            assert t_s[np.flatnonzero(duty > 0)[-1] + 1] == at_s, c.method


def test_every_trip_drawn_has_a_cross_and_a_legend_entry(tuned, figure):
    result, _ = tuned
    curves = tune_figure.curves(result, *tuned[1:], functools.partial(describe, result.problem))
    tripped = [c for c in curves if c.candidate.run.tripped[0]]
    assert len(tripped) >= 3
    legend = _legend(figure)
    crosses = [line for line in figure.axes[0].get_lines() if line.get_marker() == TRIP_MARKER]
    for curve in tripped:
        at_s, reason = curve.trip
        label = f"{curve.candidate.method} trips: {reason} at {at_s:.0f} s"
        assert label in legend
        cross = next(line for line in crosses if line.get_label() == label)
        run = curve.candidate.run
        assert cross.get_xdata()[0] == at_s
        assert cross.get_ydata()[0] == pytest.approx(np.interp(at_s, run.t_s, run.temp_c[:, 0]))
    assert len(crosses) == len(tripped)


def test_the_answer_and_your_gains_come_first_labelled(tuned, figure):
    result, proof = tuned
    assert proof.answer is not None and not proof.verdict.keep
    legend = _legend(figure)
    assert legend[0] == f"answer: {proof.answer.gains}"
    assert legend[1] == "your gains: Kp 12 Ki 0.4 Kd 100"
    first = figure.axes[0].get_lines()[0]
    assert first.get_label() == legend[0] and first.get_linewidth() > 2


def test_limit_cycles_are_marked_with_the_amplitude_the_metrics_print(tuned, figure):
    result, proof = tuned
    legend = _legend(figure)
    drawn = tune_figure.curves(result, proof, functools.partial(describe, result.problem))
    printed = {c.candidate.method: re.search(r"LIMIT CYCLE \+-([\d.]+) C every ([\d.]+) s", metrics_line(c.candidate))
               for c in drawn if not c.candidate.run.tripped[0]}
    cycling = {method: m.groups() for method, m in printed.items() if m}
    assert cycling, "a drawn candidate limit-cycles on hotend_cartridge: the case this test needs"
    marked = {m.group(1): m.groups()[1:] for text in legend
              if (m := re.fullmatch(r"(.+): limit cycle \+-([\d.]+) C every ([\d.]+) s", text))}
    assert marked == cycling
    bars = [c for c in figure.axes[0].containers if type(c).__name__ == "ErrorbarContainer"]
    assert len(bars) == len(cycling)


def test_the_title_says_heater_source_and_verdict(tuned, figure):
    result, proof = tuned
    title = figure.get_suptitle()
    hold = re.search(r"hold ([\d.]+) -> ([\d.]+) C", proof.verdict.why)
    assert title == f"hotend, hotend_cartridge: new gains, hold {hold[1]} -> {hold[2]} C (worst plant and seed)"


def test_the_history_panel_only_when_asked_in_plain_numbers(tuned, figure):
    result, proof = tuned
    assert len(figure.axes) == 2
    searched = tune(preset_problem("hotend_cartridge", 210), method="de", budget=40, seed=0, yours=YOURS)
    fig = tune_figure.draw(searched, None, "t", functools.partial(describe, searched.problem), history=True)
    fig.canvas.draw()
    panel = fig.axes[2]
    assert panel.get_ylabel() == "best cost (the objective)"
    labels = [t.get_text() for t in panel.get_yticklabels(which="both") if t.get_text()]
    assert labels and all(re.fullmatch(r"-?[\d.]+(e[+-]\d+)?", text) for text in labels), labels
