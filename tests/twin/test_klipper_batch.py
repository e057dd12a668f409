"""Klipper's loop in lanes (twin/klipper_batch.py) against ``KlipperTwin``, lane for lane.

Klipper's host computes in float and so does the kernel, in the same order; the MCU's summed ADC
readings are integers. So the readings the host gets, its duty and its shutdowns must be equal, and
the plant's temperatures within 1e-9 C: the kernel adds the soft PWM's on-intervals through step
tables, the scalar twin its per-tick on-fractions through input maps (measured about 3e-11 C apart
after 900 s). Each test runs a few hundred seconds of virtual time.
"""

from __future__ import annotations

import numpy as np
import pytest

from twin.clock import tick_near
from twin.klipper_batch import KlipperBatch, gains_setups
from twin.klipper_twin import KlipperTwin, extruder_setup
from twin.plants import ONION_RADIATING_PARAMS, make_plant

PLANT_TOLERANCE_C = 1e-9  # see the module docstring
GAINS = np.array([[22.2, 1.08, 114.0], [30.0, 2.0, 50.0], [0.05, 0.0, 0.0]])  # the last heats too slowly


def _fan_on(plant) -> None:
    plant.set_inputs(1.0, 0.0, plant.ambient_c)


def _scalar(preset: str, gains, duration_s: float, fan_at_s: float | None, **config):
    plant = make_plant(preset, **config.pop("params", {}))
    twin = KlipperTwin([extruder_setup(plant, pid_kp=gains[0], pid_ki=gains[1], pid_kd=gains[2], **config)])
    if fan_at_s is not None:
        def fan(t: KlipperTwin) -> None:
            channel = t.channels["extruder"]
            channel.advance_plant(tick_near(t.time_s))
            _fan_on(channel.plant)
        twin.schedule(fan_at_s, fan)
    twin.set_target("extruder", 200.0)
    twin.run_until(duration_s)
    return twin


def _batch(preset: str, gains, duration_s: float, fan_at_s: float | None, threads: int = 2, **config):
    plant = make_plant(preset, **config.pop("params", {}))
    batch = KlipperBatch(gains_setups(extruder_setup(plant, **config), gains), threads=threads)
    if fan_at_s is not None:
        batch.schedule(fan_at_s, lambda b: [_fan_on(p) for p in b.plants])
    batch.set_target(200.0)
    batch.run_until(duration_s)
    return batch


def _assert_lanes_are_the_twins(preset: str, gains, duration_s: float, fan_at_s: float | None = None, **config):
    batch = _batch(preset, gains, duration_s, fan_at_s, **dict(config))
    lanes = batch.result().hotend
    for lane, g in enumerate(gains):
        twin = _scalar(preset, g, duration_s, fan_at_s, **dict(config))
        scalar = twin.result().hotend
        rows = len(scalar.t_s)  # a shut-down twin reports no more; its lane holds its last report
        np.testing.assert_array_equal(lanes.t_s[:rows], scalar.t_s)
        np.testing.assert_array_equal(lanes.measured_c[:rows, lane], scalar.measured_c)
        np.testing.assert_array_equal(lanes.duty[:rows, lane], scalar.duty)
        np.testing.assert_allclose(lanes.block_c[:rows, lane], scalar.block_c, rtol=0, atol=PLANT_TOLERANCE_C)
        assert batch.halted[lane] == twin.halted
    return batch


def test_lanes_are_klipper_twins_through_a_fan_kick_and_a_verify_heater_shutdown():
    batch = _assert_lanes_are_the_twins("hotend_cartridge", GAINS, 300.0, fan_at_s=200.0)
    assert batch.halted.tolist() == [False, False, True]  # "not heating at expected rate"


def test_the_adc_range_check_shuts_a_lane_down_as_the_mcu_does():
    """max_temp 205 C: an overshooting lane reads outside the range 4 reports in a row."""
    batch = _assert_lanes_are_the_twins("hotend_cartridge", GAINS[:2], 200.0, max_temp_c=205.0)
    assert batch.halted.any()


def test_dead_time_lanes_are_klipper_twins():
    """seed 003's plant with its 5 s dead time: the plant sees each PWM value 5 s late."""
    _assert_lanes_are_the_twins("seed003_third", np.array([[8.0, 0.05, 100.0], [20.0, 0.1, 300.0]]), 300.0)


def test_radiating_lanes_are_klipper_twins():
    _assert_lanes_are_the_twins("hotend_cartridge", GAINS[:2], 200.0, params=ONION_RADIATING_PARAMS)


def test_threads_give_the_same_numbers():
    gains = np.column_stack([np.linspace(5, 40, 12), np.linspace(0.1, 3, 12), np.linspace(20, 200, 12)])
    one, two = (_batch("hotend_cartridge", gains, 100.0, None, threads=t).result().hotend for t in (1, 2))
    np.testing.assert_array_equal(one.measured_c, two.measured_c)
    np.testing.assert_array_equal(one.block_c, two.block_c)


def test_a_batch_runs_one_heater_configuration():
    setup = extruder_setup(make_plant("hotend_cartridge"))
    other = extruder_setup(make_plant("hotend_cartridge"), max_temp_c=300.0)
    with pytest.raises(ValueError, match="lane 1: every lane needs lane 0's heater settings"):
        KlipperBatch([setup, other])
    with pytest.raises(ValueError, match="plants: one per row of gains"):
        gains_setups(setup, GAINS, plants=[setup.plant])
