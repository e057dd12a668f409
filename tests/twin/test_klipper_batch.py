"""Klipper's loop in lanes (twin/klipper_batch.py) against ``KlipperTwin``, lane for lane.

Klipper's host computes in float and so does the kernel, in the same order; the MCU's summed ADC
readings are integers. So the readings the host gets, its duty and its shutdowns must be equal, and
the plant's temperatures within 1e-9 C: the kernel adds the soft PWM's on-intervals through step
tables, the scalar twin its per-tick on-fractions through input maps (measured about 3e-11 C apart
after 900 s). Each test runs a few hundred seconds of virtual time.

With ADC noise, a lane with seed s and noise n draws what ``KlipperTwin([setup], seed=s)`` draws, so
the same equalities hold: the analog value before the noise agrees to about 1e-10 LSB (the plant's
rounding, libm's exp and cbrt against numpy's), and a count could differ only if a noisy value fell that
near an integer, about one conversion in 1e10.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_port.thermistor import KLIPPER_SENSORS
from tools.tuning.evaluate import preset_problem, run_scalars, simulate
from twin import klipper_kernel as kk
from twin.clock import tick_near
from twin.klipper_batch import KlipperBatch, gains_setups
from twin.klipper_twin import PULLUP_OHM, KlipperTwin, calc_adc, extruder_setup, kalico_extruder_setup
from twin.plants import ONION_RADIATING_PARAMS, make_plant

PLANT_TOLERANCE_C = 1e-9  # see the module docstring
GAINS = np.array([[22.2, 1.08, 114.0], [30.0, 2.0, 50.0], [0.05, 0.0, 0.0]])  # the last heats too slowly


def _fan_on(plant) -> None:
    plant.set_inputs(1.0, 0.0, plant.ambient_c)


def _scalar(preset: str, gains, duration_s: float, fan_at_s: float | None, noise_lsb: float = 0.0, seed: int = 0,
            **config):
    plant = make_plant(preset, **config.pop("params", {}))
    setup = extruder_setup(plant, pid_kp=gains[0], pid_ki=gains[1], pid_kd=gains[2], **config)
    twin = KlipperTwin([dataclasses.replace(setup, noise_lsb=noise_lsb)], seed=seed)
    if fan_at_s is not None:
        def fan(t: KlipperTwin) -> None:
            channel = t.channels["extruder"]
            channel.advance_plant(tick_near(t.time_s))
            _fan_on(channel.plant)
        twin.schedule(fan_at_s, fan)
    twin.set_target("extruder", 200.0)
    twin.run_until(duration_s)
    return twin


def _batch(preset: str, gains, duration_s: float, fan_at_s: float | None, threads: int = 2, noise_lsb=None,
           seed=None, **config):
    plant = make_plant(preset, **config.pop("params", {}))
    setups = gains_setups(extruder_setup(plant, **config), gains)
    if noise_lsb is not None:
        setups = [dataclasses.replace(s, noise_lsb=n) for s, n in zip(setups, noise_lsb)]
    batch = KlipperBatch(setups, seed=seed, threads=threads)
    if fan_at_s is not None:
        batch.schedule(fan_at_s, lambda b: [_fan_on(p) for p in b.plants])
    batch.set_target(200.0)
    batch.run_until(duration_s)
    return batch


def _assert_lanes_are_the_twins(preset: str, gains, duration_s: float, fan_at_s: float | None = None,
                                noise_lsb=None, seeds=None, **config):
    """Each lane against its own twin; with noise_lsb (per lane) and seeds (per lane), that twin's noise."""
    batch = _batch(preset, gains, duration_s, fan_at_s, noise_lsb=noise_lsb, seed=seeds, **dict(config))
    lanes = batch.result().hotend
    for lane, g in enumerate(gains):
        noise = {} if noise_lsb is None else {"noise_lsb": noise_lsb[lane], "seed": seeds[lane]}
        twin = _scalar(preset, g, duration_s, fan_at_s, **noise, **dict(config))
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


@pytest.mark.parametrize("noisy", [False, True])
def test_threads_give_the_same_numbers(noisy):
    gains = np.column_stack([np.linspace(5, 40, 12), np.linspace(0.1, 3, 12), np.linspace(20, 200, 12)])
    noise = {"noise_lsb": np.linspace(0.0, 2.0, 12), "seed": [1, 2, 3] * 4} if noisy else {}
    one, two = (_batch("hotend_cartridge", gains, 100.0, None, threads=t, **noise).result().hotend for t in (1, 2))
    np.testing.assert_array_equal(one.measured_c, two.measured_c)
    np.testing.assert_array_equal(one.block_c, two.block_c)


def test_a_batch_runs_one_heater_configuration():
    setup = extruder_setup(make_plant("hotend_cartridge"))
    other = extruder_setup(make_plant("hotend_cartridge"), max_temp_c=300.0)
    with pytest.raises(ValueError, match="lane 1: every lane needs lane 0's heater settings"):
        KlipperBatch([setup, other])
    with pytest.raises(ValueError, match="plants: one per row of gains"):
        gains_setups(setup, GAINS, plants=[setup.plant])


# -- ADC noise ---------------------------------------------------------------------------------------
NOISY_GAINS = np.array([[22.2, 1.08, 114.0], [22.2, 1.08, 114.0], [10.0, 0.3, 50.0], [22.2, 1.08, 114.0],
                        [10.0, 0.3, 50.0], [30.0, 2.0, 50.0]])
NOISE_LSB = [1.0, 0.0, 2.5, 1.0, 0.5, 3.0]
SEEDS = [3, 3, 3, 7, 11, 3]  # lanes 0, 1, 2 and 5 share seed 3's draw (lane 1 noiseless); 3 and 4 their own


def test_noisy_lanes_are_klipper_twins_seed_for_seed():
    """Through the heat-up, the hold in the PID band and a fan kick (a second stretch of draws): every
    lane reads its own scalar twin's noisy readings, whether its seed is shared or its own."""
    batch = _assert_lanes_are_the_twins("hotend_cartridge", NOISY_GAINS, 400.0, fan_at_s=250.0,
                                        noise_lsb=NOISE_LSB, seeds=SEEDS)
    hotend = batch.result().hotend
    held = hotend.t_s > 150.0
    assert not batch.halted.any()
    assert np.all(np.abs(hotend.measured_c[held] - 200.0) < 15.0)  # in the band and holding
    # the noise is there: lanes 0, 1 and 3 run the same gains, noisy (seed 3), noiseless, noisy (seed 7)
    assert not np.array_equal(hotend.measured_c[:, 0], hotend.measured_c[:, 1])
    assert not np.array_equal(hotend.measured_c[:, 0], hotend.measured_c[:, 3])


def test_a_seed_is_one_draw_however_many_lanes_share_it():
    """Common random numbers: a lane reads the same with its seed alone or shared with others; no seed
    means KlipperTwin's default, 0."""
    alone = _batch("hotend_cartridge", NOISY_GAINS[:1], 150.0, None, noise_lsb=[1.0], seed=3).result().hotend
    shared = _batch("hotend_cartridge", NOISY_GAINS, 150.0, None, noise_lsb=NOISE_LSB, seed=SEEDS).result().hotend
    np.testing.assert_array_equal(shared.measured_c[:, 0], alone.measured_c[:, 0])
    default = _batch("hotend_cartridge", NOISY_GAINS[:1], 150.0, None, noise_lsb=[1.0]).result().hotend
    np.testing.assert_array_equal(default.measured_c[:, 0], _scalar("hotend_cartridge", NOISY_GAINS[0], 150.0, None,
                                                                    noise_lsb=1.0).result().hotend.measured_c)


def test_the_uncompiled_kernel_reads_the_noisy_twins(monkeypatch):
    """The kernel as plain Python (what runs without numba) against the scalar twins."""
    for name, value in vars(kk).items():
        if hasattr(value, "py_func"):
            monkeypatch.setattr(kk, name, value.py_func)
    _assert_lanes_are_the_twins("hotend_cartridge", NOISY_GAINS[[0, 2]], 130.0, noise_lsb=[1.0, 2.0], seeds=[3, 5])


@pytest.mark.parametrize("sensor", KLIPPER_SENSORS)
def test_a_noisy_conversions_analog_value_is_calc_adcs(sensor):
    """The kernel's analog value of every Klipper sensor (Cardano's and beta's closed form) against the
    scalar twin's ``calc_adc * 4096``: within 1e-10 LSB (libm's exp and cbrt against numpy's, the
    difference grown by Cardano's cancellation: measured up to 2.5e-11 LSB)."""
    part = KLIPPER_SENSORS[sensor]
    sp = KlipperBatch([dataclasses.replace(extruder_setup(make_plant("hotend_cartridge")), sensor=sensor)]).sensor_p
    temps_c = np.random.default_rng(5).uniform(0.0, 320.0, 2000)
    kernel = np.array([kk._analog(t, sp) for t in temps_c])
    np.testing.assert_allclose(kernel, calc_adc(part, PULLUP_OHM, temps_c) * 4096.0, rtol=0, atol=1e-10)


def test_bad_noise_and_seeds_are_refused():
    setups = gains_setups(extruder_setup(make_plant("hotend_cartridge")), GAINS)
    with pytest.raises(ValueError, match=r"\[extruder\] noise_lsb=inf: must be a finite number"):
        KlipperBatch([dataclasses.replace(setups[0], noise_lsb=np.inf), *setups[1:]])
    with pytest.raises(ValueError, match=r"seed: one value, or one per lane \(3\), not 2"):
        KlipperBatch(setups, seed=[1, 2])


@pytest.mark.parametrize("loop", ["klipper", "kalico"])
def test_the_tuners_klipper_batch_is_its_scalar_twins_with_noise(loop):
    """tools.tuning.evaluate: a noisy Klipper-loop (or Kalico-loop) problem gives the same trace and trips on
    the batch (simulate, Problem.batched) as one KlipperTwin per candidate (run_scalars); the last candidate
    heats too slowly and trips verify_heater."""
    problem = dataclasses.replace(preset_problem("hotend_cartridge", 210, loop=loop), noise_lsb=1.0, seed=3)
    problem = dataclasses.replace(problem, scenario=dataclasses.replace(problem.scenario, duration_s=400.0))
    assert problem.batched
    params = np.array([[22.2, 1.08, 114.0], [10.0, 0.3, 50.0], [0.05, 0.0, 0.0]])
    batch, scalar = simulate(problem, params), run_scalars(problem, params)
    np.testing.assert_array_equal(batch.t_s, scalar.t_s)
    np.testing.assert_array_equal(batch.temp_c, scalar.temp_c)
    np.testing.assert_array_equal(batch.duty, scalar.duty)
    np.testing.assert_array_equal(batch.tripped, scalar.tripped)
    assert batch.tripped.tolist() == [False, False, True]


# -- Kalico --------------------------------------------------------------------------------------------
def test_kalico_lanes_are_kalico_twins():
    """Kalico's pid lanes (firmware_port/kalico: Klipper's ControlPID, Kalico's PWM rules): max_power 0.6,
    where Kalico's absolute 0.05 threshold is not Klipper's 0.03, and lost_update_tolerance 0 (resend one
    report earlier than 2). The same gains on Klipper's rules send other values."""
    options = {"max_power": 0.6, "lost_update_tolerance": 0}
    gains = GAINS[:2]
    batch = KlipperBatch(gains_setups(kalico_extruder_setup(make_plant("hotend_cartridge"), **options), gains))
    batch.set_target(200.0)
    batch.run_until(300.0)
    lanes = batch.result().hotend
    for lane, (kp, ki, kd) in enumerate(gains):
        setup = kalico_extruder_setup(make_plant("hotend_cartridge"), pid_kp=kp, pid_ki=ki, pid_kd=kd, **options)
        twin = KlipperTwin([setup])
        twin.set_target("extruder", 200.0)
        twin.run_until(300.0)
        scalar = twin.result().hotend
        np.testing.assert_array_equal(lanes.measured_c[:, lane], scalar.measured_c)
        np.testing.assert_array_equal(lanes.duty[:, lane], scalar.duty)
        np.testing.assert_allclose(lanes.block_c[:, lane], scalar.block_c, rtol=0, atol=PLANT_TOLERANCE_C)
    klipper = _batch("hotend_cartridge", gains, 300.0, None, max_power=0.6).result().hotend
    assert not np.array_equal(klipper.duty, lanes.duty)


def test_a_batch_runs_kalicos_pid_only():
    setup = kalico_extruder_setup(make_plant("hotend_cartridge"), control="pid_v")
    with pytest.raises(ValueError, match="a Klipper batch runs control: pid, not 'pid_v'"):
        KlipperBatch([setup])
