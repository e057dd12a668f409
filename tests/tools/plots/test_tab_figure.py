"""The OctoPrint tab's figure (tools/plots/tab_figure.py), found in its artists: sized for the tab, the answer and
your gains labelled as twin-tune labels them, each drawn on the temperature and on the duty panel from the runs it
was scored on, the target marked, and only your gains where the verdict keeps them. One real tune: the rules on
hotend_cartridge (its nominal plant, seeded), proven on one seed, your gains given (as test_tune_figure.py)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from tools.cli.tune_work import describe
from tools.plots import tab_figure

pytestmark = pytest.mark.slow  # the tune and its proof (conftest.py's tuned): about 5 s on a quiet machine


def _draw(result, proof):
    return tab_figure.draw(result, proof, functools.partial(describe, result.problem))


def test_the_answer_and_your_gains_labelled_on_temperature_and_duty(tuned):
    result, proof = tuned
    assert proof.answer is not None and not proof.verdict.keep, "the case this test needs: new gains"
    fig = _draw(result, proof)
    temp_ax, duty_ax = fig.axes
    labels = [line.get_label() for line in temp_ax.get_lines()]
    answer_label = f"answer: {proof.answer.gains}"
    assert labels[0] == answer_label and labels[1] == f"your gains: {result.yours.gains}"
    assert [t.get_text() for t in fig.legends[0].get_texts()][:2] == labels[:2]
    for candidate, temp_line, duty_line in zip((proof.answer, result.yours), temp_ax.get_lines(), duty_ax.get_lines()):
        run = candidate.run
        assert np.array_equal(temp_line.get_xdata(), run.t_s)  # neither trips: the whole run
        assert np.array_equal(temp_line.get_ydata(), run.temp_c[:, 0])
        assert np.allclose(duty_line.get_ydata(), 100.0 * run.duty[:, 0])
        assert temp_line.get_color() == duty_line.get_color()
    target = [line for line in temp_ax.get_lines() if np.all(np.asarray(line.get_ydata()) == 210.0)]
    assert target, "the target is marked"
    assert temp_ax.get_ylim()[0] == pytest.approx(210.0 - tab_figure.BELOW_TARGET_C)


def test_the_figure_is_made_for_the_tabs_width(tuned, tmp_path):
    result, proof = tuned
    path = tmp_path / "tab.png"
    tab_figure.write(path, result, proof, functools.partial(describe, result.problem))
    from matplotlib.image import imread

    height, width = imread(path).shape[:2]
    assert (width, height) == (tab_figure.WIDTH_PX, tab_figure.HEIGHT_PX)


def test_keep_your_gains_draws_yours_alone(tuned):
    result, proof = tuned
    from dataclasses import replace

    kept = replace(proof, answer=None)
    fig = _draw(result, kept)
    labels = [text.get_text() for text in fig.legends[0].get_texts()]
    assert labels == [f"your gains: {result.yours.gains}"]


def test_twin_tune_writes_it_with_plot_compact(tmp_path, capsys):
    from matplotlib.image import imread

    from tools.cli.tune import main

    path = tmp_path / "tab.png"
    assert main(["--plant", "hotend", "--budget", "40", "--proof", "1", "--cross-check", "0", "--plot", "none",
                 "--plot-compact", str(path)]) in (0, 1)
    assert imread(path).shape[:2] == (tab_figure.HEIGHT_PX, tab_figure.WIDTH_PX)
    assert main(["--plant", "hotend", "--plot-compact", str(tmp_path / "tab.txt")]) == 2
    assert "--plot-compact" in capsys.readouterr().err.splitlines()[-1]
