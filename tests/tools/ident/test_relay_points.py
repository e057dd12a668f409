"""tools/ident/relay_points.py: printed relay cycles as measured points of the loop, and the fit to them."""

import numpy as np
import pytest

from tools.ident.relay_loop import Relay, relay_cycle
from tools.ident.relay_points import (
    CYCLE_SCATTER_SWING_REL,
    CYCLE_SCATTER_TU_REL,
    RelayPoint,
    fit_points,
    klipper_points,
    marlin_points,
)
from tools.logs import load_log
from twin.plants import TransferFunction

ENDER = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"
ARTILLERY_BED = "m303_bed_artillery_genius_pro_S60_configs641.txt"
PID_RESULTS = "klipper_pid_calibrate_results_collection.txt"
AMBIENT_C = 25.0


def test_ender_points_levels_and_bias_brackets(hardware_logs):
    """Each cycle ran at the levels of the bias line before it; Marlin's next update, truncated toward
    zero, brackets t_high - t_low: 87 -> 84 with d 87 means -4 < 87 (t_high - t_low) / Tu <= -3."""
    points = marlin_points(load_log(hardware_logs / ENDER), "extruder", 210.0)
    assert [p.tu_s for p in points] == [10.58, 10.74, 10.26, 10.42]
    assert [round(p.relay.on_duty * 127) for p in points] == [87, 87, 84, 84]  # (bias + d) >> 1 of the line before
    assert all(p.relay.off_duty == 0.0 and p.relay.target_c == 210.0 for p in points)
    assert points[0].levels_note and points[0].asymmetry_s is None  # the capture starts with its bias line
    low, high = points[1].asymmetry_s
    assert (low, high) == pytest.approx((-4 * 10.74 / 87, -3 * 10.74 / 87))
    assert points[2].asymmetry_s == pytest.approx((-10.26 / 84, 10.26 / 84))  # 84 -> 84: within one step


def test_scatter_constants_are_the_artillery_beds(hardware_logs):
    """The cycle-to-cycle scatter the residuals are divided by: the Artillery bed's six printed cycles."""
    cycles = [c for c in load_log(hardware_logs / ARTILLERY_BED).cycles if c.tu_s]
    tu = np.array([c.tu_s for c in cycles])
    swing = np.array([c.max_c - c.min_c for c in cycles])
    assert len(cycles) == 6
    assert round(float(np.std(tu, ddof=1) / tu.mean()), 2) == CYCLE_SCATTER_TU_REL
    assert round(float(np.std(swing, ddof=1) / swing.mean()), 2) == CYCLE_SCATTER_SWING_REL


def _points(spec, levels, target_c=210.0):
    """Exact points of a known plant: its own cycles at these levels, t_high - t_low bracketed by 0.1 s."""
    out = []
    for i, (on, off) in enumerate(levels):
        c = relay_cycle(spec, AMBIENT_C, Relay.marlin(target_c, on, off))
        a = c.t_high_s - c.t_low_s
        out.append(RelayPoint(i, Relay.marlin(target_c, on, off), c.tu_s, c.swing_c, c.min_c, c.max_c,
                              (a - 0.05, a + 0.05)))
    return out


@pytest.mark.slow
def test_fit_recovers_a_known_fopdt_from_its_cycles():
    """Two cycles at different levels: gain, time constant and dead time back within 2 % (the start
    values come from the describing function; the relay cycle itself is exact here)."""
    truth = TransferFunction(450.0, 1.0, lag1_s=150.0, delay_s=4.0)
    result = fit_points("fopdt", _points(truth, [(0.7, 0.0), (0.6, 0.1)]), AMBIENT_C)
    for name, value in {"gain_c": 450.0, "time_constant_s": 150.0, "delay_s": 4.0}.items():
        assert result.params[name] == pytest.approx(value, rel=0.02), name
    assert set(result.identification().values()) == {"identified"}
    assert result.evidence == "relay results" and result.fixed["ambient_c"] == AMBIENT_C


def test_pid_calibrate_results_fit_with_the_gain_held(hardware_logs):
    """One Klipper result is two numbers (Tu, swing): the dead time and lag are fitted to them exactly,
    the static gain held (Klipper prints no bias to tell it)."""
    (entry,) = [r for r in load_log(hardware_logs / PID_RESULTS) if r.tu_s == pytest.approx(57.6, abs=0.1)]
    (point,) = klipper_points([entry], 200.0)
    result = fit_points("fopdt", [point], AMBIENT_C, fixed={"gain_c": 500.0})
    assert set(result.params) == {"time_constant_s", "delay_s"} and result.fixed["gain_c"] == 500.0
    cycle = relay_cycle(result.spec(), AMBIENT_C, point.relay)
    assert cycle.tu_s == pytest.approx(entry.tu_s, rel=1e-3) and cycle.swing_c == pytest.approx(entry.peak_to_peak_c,
                                                                                                rel=1e-3)
