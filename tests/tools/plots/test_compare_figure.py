"""twin-compare's figure (tools/plots/compare_figure.py) on a real replay: where the twin shut down, a cross on its
trace at the time the replay reports and a legend entry naming why; the title in a user's words. The shutdown is
made real: chesleavens' bed heat-up (26 -> 65 C) replayed with max_power 0.05, so Klipper's verify_heater shuts the
twin down: "not heating at expected rate"."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tools.logs import load_log
from tools.plots import compare_figure
from tools.plots.marks import TRIP_MARKER
from tools.validation import compare

CHES = "klippy_stats_chesleavens_cartesian_stm32f103.csv"
MAX_POWER = 0.05  # of the heater's power: too weak to heat at the rate verify_heater asks


@pytest.fixture(scope="module")
def shut_down(hardware_logs):
    log = load_log(hardware_logs / CHES)
    fit, seg, windows = compare.fit_heater(log, "heater_bed")
    info = replace(compare.heater_info(log, "heater_bed"), max_power=MAX_POWER)
    return compare.score_replay(CHES, "heater_bed", fit, seg.label, info, windows[0], True)


def test_the_replay_says_when_the_twin_shut_down(shut_down):
    r = shut_down
    t_s, _, twin_c, _, _ = r.trace
    assert r.shutdown is not None and r.shutdown_s is not None
    assert t_s[0] < r.shutdown_s < t_s[-1]
    before = t_s < r.shutdown_s
    assert r.shutdown.startswith("Heater heater_bed not heating at expected rate")
    assert np.ptp(twin_c[~before]) == 0 and np.ptp(twin_c[before][-10:]) > 0  # no report after it, rising before


def test_the_shutdown_is_marked_and_named(shut_down):
    r = shut_down
    reason = r.shutdown.splitlines()[0]
    trace = compare_figure.Trace("heater_bed: the twin replays", *r.trace, trip=(r.shutdown_s, reason))
    fig = compare_figure.draw([trace], f"{CHES}: the log against the twin")
    ax = fig.axes[0]
    (cross,) = [line for line in ax.get_lines() if line.get_marker() == TRIP_MARKER]
    t_s, _, twin_c, _, _ = r.trace
    assert cross.get_xdata()[0] == r.shutdown_s
    assert cross.get_ydata()[0] == pytest.approx(np.interp(r.shutdown_s, t_s, twin_c))
    legend = [text.get_text() for text in fig.axes[-1].get_legend().get_texts()]
    assert f"the twin trips: {reason} at {r.shutdown_s:.0f} s" in legend
    assert legend[:2] == ["logged temperature", "the twin's temperature"]
    assert fig.get_suptitle() == f"{CHES}: the log against the twin"
