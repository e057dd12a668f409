"""M303 captures: the relay trace made fit for identification (tools/ident/relay_trace.py) and the twin's
M303 against the capture (tools/validation/m303_compare.py, twin-compare)."""

import numpy as np
import pytest

from tools.cli import compare as compare_cli
from tools.ident.segments import NotFittable, log_segments
from tools.logs import load_log
from tools.validation import m303_compare
from tools.validation.m303_compare import GOAL_TU_REL, IN, relay_stats, twin_noise_lsb
from twin.sensor import SensorChain
from tools.ident.relay_trace import AMBIENT_PRIOR_C, ambient_hint_c, estimate_target_c, switch_instants

ENDER = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"
PRUSA_BED = "m303_bed_and_hotend_octoprint_calibrationcompanion26_partial.txt"


def test_switch_put_at_the_target_crossing_and_not_compared():
    t_s = np.array([0.0, 2.0, 4.0, 6.0])
    temp_c = np.array([206.0, 208.0, 212.0, 213.0])
    duty = np.array([0.7, 0.7, 0.0, 0.0])
    t, temp, u, seen = switch_instants(t_s, temp_c, duty, 210.0)
    assert t.tolist() == [0.0, 2.0, 3.0, 4.0, 6.0]  # 208 -> 212 crosses 210 halfway
    assert u.tolist() == [0.7, 0.7, 0.0, 0.0, 0.0] and seen.tolist() == [True, True, False, True, True]
    assert temp[2] == 210.0


def test_switch_midway_when_the_readings_do_not_straddle_the_target():
    t, _, _, _ = switch_instants(np.array([0.0, 2.0]), np.array([211.0, 212.0]), np.array([1.0, 0.0]), 210.0)
    assert t.tolist() == [0.0, 1.0, 2.0]


def test_target_estimated_from_the_switches():
    temp_c = np.array([207.0, 209.0, 212.0, 213.0, 211.0, 208.0])
    on = np.array([True, True, False, False, False, True])
    assert estimate_target_c(temp_c, on) == 210.0  # midpoints 210.5 and 209.5
    assert estimate_target_c(temp_c, np.ones(6, bool)) is None


def test_ambient_from_the_idle_bed_else_the_prior(hardware_logs):
    assert ambient_hint_c(load_log(hardware_logs / ENDER)) == 30.0  # B:30.00 /0.00 ... B@:0
    # the Artillery bed run's idle hotend reads 56-61 C: still hot, not the room
    assert ambient_hint_c(load_log(hardware_logs / "m303_bed_artillery_genius_pro_S60_configs641.txt")) \
        == AMBIENT_PRIOR_C


def test_bed_capture_without_its_m303_line_by_heater_flag(hardware_logs):
    """The Prusa bed run's M303 line is not in the capture (only the later hotend's M303 E0 S215): the
    bed is chosen by --heater heater_bed, its target found in the data (the switches), not taken from E0's S215."""
    log = load_log(hardware_logs / PRUSA_BED)
    heater, (seg,) = log_segments(log, "heater_bed")
    assert heater == "heater_bed" and seg.target_c == 60.0 and "found in the data" in seg.note
    assert not seg.observed.all()  # switch instants inserted, and the burn-in before the first one
    with pytest.raises(NotFittable):
        log_segments(log, "extruder")  # the hotend's 10-line heat-up is too short


def test_relay_stats_means_over_the_printed_cycles(hardware_logs):
    stats = relay_stats(load_log(hardware_logs / ENDER).cycles)
    assert stats.cycles == 4 and stats.tu_s == pytest.approx((10.58 + 10.74 + 10.26 + 10.42) / 4)
    assert stats.swing_c == pytest.approx(np.mean([214.37 - 206.02, 214.53 - 206.25, 213.75 - 206.21, 213.83 - 206.25]))


@pytest.mark.parametrize(("temp_c", "noise_c"), [(60.0, 0.05), (210.0, 0.1)])
def test_twin_noise_gives_the_readings_the_noise_asked_for(temp_c, noise_c):
    """A reading is the table value of OVERSAMPLENR conversions summed: with the noise per conversion
    twin_noise_lsb(noise_c, T) (about 1 LSB for these), the sums scatter by noise_c through the
    chain's slope at T. 4000 sums: the standard deviation's sampling error is about 1.1 %, and
    Widrow's model of the dithered floor holds to within a per cent at 1 LSB: within 5 %."""
    chain = SensorChain(noise_lsb=twin_noise_lsb(noise_c, temp_c), rng=np.random.default_rng(1))
    counts = chain.convert(np.full((4000, 16), temp_c), np.zeros((4000, 16), dtype=np.int64))
    readings_c = counts.sum(axis=1) / 16 / chain.lsb_per_c(temp_c)
    assert np.std(readings_c) == pytest.approx(noise_c, rel=0.05)
    assert twin_noise_lsb(0.001, temp_c) == 0.0  # the floor alone scatters more than that
    # about 4.8 counts per kelvin at 60 C for a 100k B3950 on a 4.7k pull-up, 1.8 at 210 C
    assert SensorChain().lsb_per_c(temp_c) == pytest.approx({60.0: 4.8, 210.0: 1.8}[temp_c], rel=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("capture", [ENDER, PRUSA_BED])
def test_twin_compare_m303_in_sample_is_listed_not_counted(capture, capsys, hardware_logs):
    """Fitted on all its printed cycles, a capture gives in-sample rows only: listed, and the summary
    counts none of them; every line within 120 columns."""
    assert compare_cli.main([str(hardware_logs / capture)]) == 0
    out = capsys.readouterr().out
    assert any(line.startswith(IN) and "listed, not scored" not in line for line in out.splitlines())
    assert "summary: no out-of-sample row" in out
    assert max(len(line) for line in out.splitlines()) <= 120


@pytest.mark.slow
def test_a_noiseless_twin_crosses_a_bed_target_late(hardware_logs):
    """Why the twin's ADC is dithered in the comparison: on the Prusa bed's fitted plant a noiseless
    chain (0.2 C steps at 60 C) sees each crossing up to a step late and its period comes out
    more than 10 % long (the in-sample fit, all printed cycles)."""
    r = m303_compare.m303_check(hardware_logs / PRUSA_BED, "heater_bed")
    assert r.noise_lsb == m303_compare.DITHER_LSB  # fitted to relay results: dither only
    quiet = m303_compare.run_twin_m303("fit", r.spec, r.heater, r.ambient_c, r.target_c, r.ncycles, "1.1",
                                       noise_lsb=0.0)
    (row,) = r.rows
    assert relay_stats(quiet.cycles).tu_s > (1 + GOAL_TU_REL) * row.log.tu_s
