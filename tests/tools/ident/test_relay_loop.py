"""tools/ident/relay_loop.py: the continuous relay cycle the relay-results fit compares with, checked
against the firmware-exact runs: the twin's own M303 and KlipperTwin's PID_CALIBRATE on the same plants."""

import pytest

from firmware_port.klipper.heater import PWM_RESEND_BEFORE_2025_04
from tools.ident.relay_loop import MARLIN_MIN_HALF_S, NoOscillation, Relay, relay_cycle
from tools.validation.compare import HeaterInfo, make_setup
from tools.validation.m303_compare import run_twin_m303
from twin.klipper_twin import PULLUP_OHM, PWM_CYCLE_TIME_S, KlipperTwin
from twin.plants import SPECS, Plant, TransferFunction

AMBIENT_C = 25.0
FOPDT = TransferFunction(500.0, 1.0, lag1_s=120.0, delay_s=3.0)


@pytest.mark.slow
@pytest.mark.parametrize("name, spec", [("hotend_cartridge", SPECS["hotend_cartridge"]), ("fopdt", FOPDT)])
def test_marlin_cycle_matches_the_twins_m303(name, spec):
    """At the levels of the twin's last cycle, the twin's printed Tu within 2 % and its extremes within
    one ADC step at 210 C (1.8 counts per kelvin: 0.55 C): the twin reads through a 10-bit ADC and
    heats through a soft PWM, the relay here switches at the exact crossing, one reading period late,
    on the mean duty."""
    log = run_twin_m303(name, spec, "extruder", AMBIENT_C, 210.0, 10, noise_lsb=0.5)
    before, last = log.cycles[-2], log.cycles[-1]
    on, off = ((before.bias + before.d) >> 1) / 127, ((before.bias - before.d) >> 1) / 127
    cycle = relay_cycle(spec, AMBIENT_C, Relay.marlin(210.0, on, off))
    assert cycle.tu_s == pytest.approx(last.tu_s, rel=0.02)
    assert cycle.min_c == pytest.approx(last.min_c, abs=0.55) and cycle.max_c == pytest.approx(last.max_c, abs=0.55)
    assert cycle.t_high_s + cycle.t_low_s == pytest.approx(cycle.tu_s)


@pytest.mark.slow
@pytest.mark.parametrize("spec", [FOPDT, SPECS["hotend_cartridge"]])
def test_klipper_cycle_matches_pid_calibrate(spec):
    """KlipperTwin's PID_CALIBRATE on the same plant: Tu within 2 %, peak-to-peak within 5 % (Klipper
    reads every 0.3 s, so its peaks are sampled ones)."""
    info = HeaterInfo(22.2, 1.08, 114.0, 1.0, "EPCOS 100K B57560G104F", "", PULLUP_OHM, 1.0, PWM_CYCLE_TIME_S, 0.0,
                      300.0, PWM_RESEND_BEFORE_2025_04)
    twin = KlipperTwin([make_setup(info, "extruder", Plant("x", spec, AMBIENT_C, AMBIENT_C))])
    result = twin.pid_calibrate("extruder", 200.0)
    cycle = relay_cycle(spec, AMBIENT_C, Relay.klipper(200.0))
    assert cycle.tu_s == pytest.approx(result.tu_s, rel=0.02)
    assert cycle.swing_c == pytest.approx(result.peak_to_peak_c, rel=0.05)


def test_a_fast_plant_sits_on_the_relay_floor():
    """Little lag: the reading crosses the target well within 5 s, so both half-cycles last Marlin's
    minimum and Tu is the 10 s floor (plus nothing: the minimum, not a crossing, ends each)."""
    fast = TransferFunction(500.0, 1.0, lag1_s=100.0, delay_s=0.3)
    cycle = relay_cycle(fast, AMBIENT_C, Relay.marlin(210.0, 0.75, 0.0))
    assert cycle.t_high_s == pytest.approx(MARLIN_MIN_HALF_S) and cycle.t_low_s >= MARLIN_MIN_HALF_S
    assert cycle.tu_s < 2 * MARLIN_MIN_HALF_S * 1.1


def test_the_cycle_is_smooth_in_the_plant():
    """What a least-squares fit needs: a small change of a parameter moves Tu and the extremes by a
    small, proportionate amount (no sampling-grid steps)."""
    base = relay_cycle(FOPDT, AMBIENT_C, Relay.marlin(210.0, 0.7, 0.0))
    for step in (1e-6, 1e-4):
        moved = relay_cycle(TransferFunction(500.0, 1.0, lag1_s=120.0, delay_s=3.0 * (1 + step)), AMBIENT_C,
                            Relay.marlin(210.0, 0.7, 0.0))
        slope = (moved.tu_s - base.tu_s) / (3.0 * step)
        assert 1.0 < slope < 6.0  # dTu/dL: a dead time adds to both half-cycles, and to the swing's lag


def test_levels_that_cannot_reach_the_target():
    with pytest.raises(NoOscillation, match="never above"):
        relay_cycle(FOPDT, AMBIENT_C, Relay.marlin(210.0, 0.3, 0.0))  # 25 + 0.3 x 500 = 175 C at most
