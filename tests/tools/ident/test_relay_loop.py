"""tools/ident/relay_loop.py: the continuous relay cycle the relay-results fit compares with, checked
against the firmware-exact runs: the twin's own M303 and KlipperTwin's PID_CALIBRATE on the same plants."""

import dataclasses

import pytest

from firmware_port.klipper.heater import PWM_RESEND_BEFORE_2025_04
from firmware_port.marlin.autotune import update_bias
from firmware_port.marlin.constants import PID_MAX
from tools.ident.relay_loop import (MARLIN_MIN_HALF_S, NoOscillation, Relay, marlin_levels, moving_bias_run, relay_cycle,
                                    tangent_plant)
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


@pytest.mark.slow
@pytest.mark.parametrize("name, spec", [("hotend_cartridge", SPECS["hotend_cartridge"]), ("fopdt", FOPDT)])
def test_the_moving_bias_follows_the_twins_m303(name, spec):
    """From the twin's third printed cycle on, the relay run with the bias lines the twin printed before
    it, its bias then moving by Marlin's rule: each cycle's printed bias within 2 counts (the rule
    truncates a ratio of whole ms, the twin's times fall on its 164 ms readings), the extremes within one
    ADC step (as the fixed-level cycle above), the mean Tu within 2 % and each within 6 % (the twin's
    noisy readings scatter its cycles by up to 3 % about their mean)."""
    log = run_twin_m303(name, spec, "extruder", AMBIENT_C, 210.0, 10, noise_lsb=0.5)
    printed = log.cycles
    run = moving_bias_run(spec, AMBIENT_C, 210.0, (printed[0].bias, printed[0].d), (printed[1].bias, printed[1].d),
                          PID_MAX, len(printed) - 2)
    for logged, model in zip(printed[2:], run):
        assert abs(model.next_bias - logged.bias) <= 2
        assert model.cycle.tu_s == pytest.approx(logged.tu_s, rel=0.06)
        assert model.cycle.min_c == pytest.approx(logged.min_c, abs=0.55)
        assert model.cycle.max_c == pytest.approx(logged.max_c, abs=0.55)
    pairs = list(zip(printed[2:], run))
    assert sum(m.cycle.tu_s for _, m in pairs) == pytest.approx(sum(c.tu_s for c, _ in pairs), rel=0.02)


def test_a_run_at_settled_levels_is_the_limit_cycle():
    """Settled at the levels it starts at, the run's first cycle is relay_cycle's limit cycle there."""
    bias, d = 94, 94
    first = moving_bias_run(FOPDT, AMBIENT_C, 210.0, (bias, d), (bias, d), PID_MAX, 1)[0]
    limit = relay_cycle(FOPDT, AMBIENT_C, Relay.marlin(210.0, *marlin_levels(bias, d)))
    assert first.cycle == pytest.approx(limit, abs=1e-6)


def test_the_bias_moves_as_marlins_rule_moves_it_towards_balance():
    """Started far above the duty that holds the target (185 C over ambient on a 500 C gain: 0.37, bias
    about 94 of 255), the bias falls to it within a few cycles (Marlin's rule may overshoot on the way)
    and stays, each step Marlin's rule on the cycle's own whole-ms times, the high and low times then
    balanced within a reading period."""
    run = moving_bias_run(FOPDT, AMBIENT_C, 210.0, (160, 94), (160, 94), PID_MAX, 12)
    for c, after in zip(run, run[1:]):
        assert (after.bias, after.d) == (c.next_bias, c.next_d)
        assert (c.next_bias, c.next_d) == update_bias(c.bias, c.d, round(c.cycle.t_high_s * 1000),
                                                      round(c.cycle.t_low_s * 1000), PID_MAX)
    biases = [c.bias for c in run]
    assert biases[1] < biases[0] - 40 and all(abs(b - 94) <= 3 for b in biases[-6:])
    assert abs(run[-1].cycle.t_high_s - run[-1].cycle.t_low_s) < 0.2



@pytest.mark.slow
def test_a_radiating_plant_cycles_as_its_tangent_at_the_target():
    """A hotend losing 20 cm^2 of radiation besides its linear loss, tuned at 240 C: the relay cycle at the
    levels of the twin's last cycle, on the plant linearised at the target (tangent_plant), matches the
    twin's printed Tu within 2 % and its extremes within one ADC step there (1.1 counts per kelvin at 240 C:
    0.9 C); the same plant without its radiation does not (its loss there is a third smaller)."""
    spec = dataclasses.replace(SPECS["hotend_cartridge"], emissivity=1.0, radiating_area_m2=20e-4)
    log = run_twin_m303("hotend_cartridge", spec, "extruder", AMBIENT_C, 240.0, 10, noise_lsb=0.5)
    before, last = log.cycles[-2], log.cycles[-1]
    relay = Relay.marlin(240.0, *marlin_levels(before.bias, before.d))
    cycle = relay_cycle(spec, AMBIENT_C, relay)
    assert cycle.tu_s == pytest.approx(last.tu_s, rel=0.02)
    assert cycle.min_c == pytest.approx(last.min_c, abs=0.9) and cycle.max_c == pytest.approx(last.max_c, abs=0.9)
    linear = dataclasses.replace(spec, emissivity=0.0, radiating_area_m2=0.0)
    assert relay_cycle(linear, AMBIENT_C, relay).tu_s != pytest.approx(last.tu_s, rel=0.05)


def test_the_tangent_keeps_the_loss_and_its_slope_at_the_target():
    """tangent_plant's linear loss k (T - Ta') equals the radiating loss at the target, and k its slope there
    (a central difference); a linear plant comes back as it is."""
    spec = dataclasses.replace(SPECS["hotend_cartridge"], emissivity=1.0, radiating_area_m2=20e-4)
    linear, ambient_c = tangent_plant(spec, AMBIENT_C, 240.0)

    def loss_w(t_c: float) -> float:
        return spec.ambient_xfer_w_k * (t_c - AMBIENT_C) + spec.radiation_w_k(t_c, AMBIENT_C) * (t_c - AMBIENT_C)

    assert linear.ambient_xfer_w_k * (240.0 - ambient_c) == pytest.approx(loss_w(240.0), rel=1e-12)
    assert linear.ambient_xfer_w_k == pytest.approx((loss_w(240.5) - loss_w(239.5)) / 1.0, rel=1e-6)
    assert linear.linear and tangent_plant(FOPDT, AMBIENT_C, 240.0) == (FOPDT, AMBIENT_C)
