"""Every path of the batch twin, lane for lane against the one-twin engine (twin/engine.py ``Twin``).

Integer outputs (the firmware's reading, its duty, its trips) must be equal; the plant's float state
(block temperature) within 1e-9 C: the batch sums a period's pulses through step tables, the scalar
engine through its per-tick input maps, the same exact maps in another order, which differ by a few
ulps of 200 C (about 1e-12 C measured).
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_port.fuzzy_pi import SEED004_HOTEND, FuzzyPi
from firmware_port.fuzzy_pid import FuzzyPid
from firmware_port.marlin.bangbang import BangBangHotend
from firmware_port.marlin.pid import PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND, PidFixed, PidGains
from twin.batch import BatchTwin
from twin.batch_kernel import KERNELS
from twin.engine import Twin
from twin.plants import ONION_RADIATING_PARAMS, make_plant
from twin.sensor import SensorChain, seeded_chains

BLOCK_TOLERANCE_C = 1e-9  # see the module docstring
TARGET_C = 210
TARGET_AT_S = 0.5


def _scalar(preset: str, controller, duration_s: float, seed: int = 0, noise_lsb: float = 0.0, **params):
    twin = Twin([make_plant(preset, **params)], "pid", controllers=[controller], seed=seed, noise_lsb=noise_lsb)
    twin.schedule(TARGET_AT_S, lambda t: t.board.set_target(0, TARGET_C))
    twin.run_until(duration_s)
    return twin


def _batch(preset: str, controllers, duration_s: float, **options) -> BatchTwin:
    params = options.pop("params", {})
    batch = BatchTwin(make_plant(preset, **params), controllers, **options)
    batch.schedule(TARGET_AT_S, lambda b: b.set_target(TARGET_C))
    batch.run_until(duration_s)
    return batch


def _assert_lane_is_the_twin(batch: BatchTwin, lane: int, twin: Twin) -> None:
    """Same readings and duty reading by reading (up to a trip: a halted board records on its own
    cadence), the same trip, the block within BLOCK_TOLERANCE_C."""
    scalar, lanes = twin.result().hotend, batch.result().hotend
    n = min(len(scalar.t_s), len(lanes.t_s))
    apart = np.abs(lanes.t_s[:n] - scalar.t_s[:n]) > 1e-9  # after a trip the scalar twin records every 160 ticks
    rows = int(np.argmax(apart)) if apart.any() else n
    assert rows > 0 and (rows == len(scalar.t_s) or twin.board.halted)
    np.testing.assert_array_equal(lanes.measured_c[:rows, lane], scalar.measured_c[:rows])
    np.testing.assert_array_equal(lanes.duty[:rows, lane], scalar.duty[:rows])
    np.testing.assert_allclose(lanes.block_c[:rows, lane], scalar.block_c[:rows], rtol=0, atol=BLOCK_TOLERANCE_C)
    assert bool(batch.lanes.halted[lane]) == twin.board.halted


CONTROLLERS = {
    "pid 2.1": lambda: [PidFixed(PidGains(22.2, 1.08, 114.0), PREV_TEMP_IN_BAND),
                        PidFixed(PidGains(40.0, 3.0, 60.0), PREV_TEMP_IN_BAND)],
    "pid 2.0 and 2.1": lambda: [PidFixed(PidGains(22.2, 1.08, 114.0), PREV_TEMP_EVERY_SAMPLE),
                                PidFixed(PidGains(12.0, 0.4, 100.0), PREV_TEMP_IN_BAND)],
    "bang-bang": lambda: [BangBangHotend(), BangBangHotend()],
    "fuzzy PI": lambda: [FuzzyPi(SEED004_HOTEND), FuzzyPi(SEED004_HOTEND.__class__(30.0, 1.0, 16.0))],
    "fuzzy-PID": lambda: [FuzzyPid(), FuzzyPid(PidGains(30.0, 2.0, 80.0))],
}


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("family", CONTROLLERS)
def test_every_controller_family_runs_as_its_scalar_twin(kernel, family):
    """Each law the lanes carry (compiled, and as scalar instances on the numpy lanes) equals the
    firmware's class on the board, through the heat-up, the band and the hold."""
    batch = _batch("hotend_cartridge", CONTROLLERS[family](), 150.0, kernel=kernel)
    for lane, controller in enumerate(CONTROLLERS[family]()):
        _assert_lane_is_the_twin(batch, lane, _scalar("hotend_cartridge", controller, 150.0))


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_noisy_lane_reads_what_the_scalar_twin_with_its_seed_reads(kernel):
    """Common random numbers: a lane with seed s and noise n is ``Twin(..., seed=s, noise_lsb=n)``;
    lanes naming the same seed share its normals (scaled by their own noise)."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(40.0, 3.0, 60.0), PidGains(22.2, 1.08, 114.0), PidGains(8, 0.2, 50)]
    seeds, noise = [3, 3, 3, 7], [1.0, 1.0, 2.5, 0.5]
    batch = _batch("hotend_cartridge", gains, 100.0, kernel=kernel, seed=seeds, noise_lsb=noise)
    for lane, g in enumerate(gains):
        _assert_lane_is_the_twin(batch, lane, _scalar("hotend_cartridge", PidFixed(g), 100.0, seeds[lane], noise[lane]))
    noisy = batch.result().hotend.measured_c
    assert not np.array_equal(noisy[:, 0], noisy[:, 2])  # same stream, more noise


def test_a_sensor_chain_lends_its_stream_to_every_lane():
    """``sensor=seeded_chains(1, seed, noise)[0]`` (what a tuner builds per ensemble member) gives the
    lanes the scalar twin's noise of that seed."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(40.0, 3.0, 60.0)]
    batch = _batch("hotend_cartridge", gains, 60.0, sensor=seeded_chains(1, 11, 1.5)[0])
    for lane, g in enumerate(gains):
        _assert_lane_is_the_twin(batch, lane, _scalar("hotend_cartridge", PidFixed(g), 60.0, 11, 1.5))


def test_dead_time_lanes_run_as_the_scalar_twin():
    """seed 003's third-order plant with its 5 s dead time (exact on the tick grid), and seed 001's
    FOPDT (20.7 s), whose dead time lets Marlin's full-power band overshoot into MAXTEMP: the same
    readings and the same trip at the same reading."""
    gains = [PidGains(8.0, 0.05, 100.0), PidGains(20.0, 0.1, 300.0)]
    batch = _batch("seed003_third", gains, 300.0)
    for lane, g in enumerate(gains):
        _assert_lane_is_the_twin(batch, lane, _scalar("seed003_third", PidFixed(g), 300.0))
    tripping = _batch("seed001_fopdt", gains, 200.0)
    assert tripping.lanes.trip.tolist() == ["MAXTEMP triggered"] * 2
    for lane, g in enumerate(gains):
        _assert_lane_is_the_twin(tripping, lane, _scalar("seed001_fopdt", PidFixed(g), 200.0))


@pytest.mark.slow


def test_radiating_lanes_are_relinearised_as_the_scalar_twin():
    """The radiating fit of hotend_cartridge: every period on the model of the block's 0.5 C bin."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(40.0, 3.0, 60.0)]
    batch = _batch("hotend_cartridge", gains, 150.0, params=ONION_RADIATING_PARAMS)
    for lane, g in enumerate(gains):
        _assert_lane_is_the_twin(batch, lane, _scalar("hotend_cartridge", PidFixed(g), 150.0, **ONION_RADIATING_PARAMS))


def test_lanes_on_several_plants_are_each_plant_alone():
    """An ensemble in one batch: lanes given the same plant object share it; each group equals a batch
    of its plant alone, and threads change nothing."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(40.0, 3.0, 60.0), PidGains(12.0, 0.4, 100.0)]
    nominal, slow = make_plant("hotend_cartridge"), make_plant("hotend_cartridge", sensor_responsiveness_per_s=0.05)
    mixed = BatchTwin([nominal, slow, nominal], gains, seed=[1, 2, 1], noise_lsb=1.0, threads=2)
    assert len(mixed.plants) == 2
    mixed.set_target(TARGET_C)
    mixed.run_until(80.0)
    for lane, (params, g, seed) in enumerate(zip(({}, {"sensor_responsiveness_per_s": 0.05}, {}), gains, (1, 2, 1))):
        alone = BatchTwin(make_plant("hotend_cartridge", **params), [g], seed=seed, noise_lsb=1.0, threads=1)
        alone.set_target(TARGET_C)
        alone.run_until(80.0)
        np.testing.assert_array_equal(mixed.result().hotend.measured_c[:, lane], alone.result().hotend.measured_c[:, 0])
        np.testing.assert_array_equal(mixed.result().hotend.block_c[:, lane], alone.result().hotend.block_c[:, 0])


def test_threads_give_the_same_numbers():
    rng = np.random.default_rng(4)
    gains = [PidGains(*map(float, g)) for g in rng.uniform([5, 0.1, 20], [40, 3, 200], (24, 3))]
    runs = [_batch("hotend_cartridge", gains, 60.0, threads=threads, seed=5, noise_lsb=1.0) for threads in (1, 2, 3)]
    for other in runs[1:]:
        np.testing.assert_array_equal(runs[0].result().hotend.measured_c, other.result().hotend.measured_c)
        np.testing.assert_array_equal(runs[0].result().hotend.block_c, other.result().hotend.block_c)


def test_a_batch_refuses_bad_lanes():
    with pytest.raises(ValueError, match="noise_lsb: each lane's must be a finite number in 0..100 LSB"):
        BatchTwin(make_plant("hotend"), [PidGains(1, 1, 1)], noise_lsb=-1.0)
    with pytest.raises(ValueError, match=r"seed: one value, or one per lane \(2\)"):
        BatchTwin(make_plant("hotend"), [PidGains(1, 1, 1)] * 2, seed=[1, 2, 3])
    with pytest.raises(TypeError, match="lane 1: one controller family per batch"):
        BatchTwin(make_plant("hotend"), [PidFixed(), FuzzyPi()])


def test_a_batch_without_a_trace_keeps_memory_independent_of_the_horizon():
    from twin.streaming import ScoreSpec

    gains = [PidGains(22.2, 1.08, 114.0)] * 4
    sizes = []
    for duration_s in (100.0, 400.0):
        batch = _batch("hotend_cartridge", gains, duration_s, record=False,
                       score=ScoreSpec(TARGET_C, 25.0, 50.0, 2.0, 1))
        sizes.append(batch.bytes_per_lane())
        with pytest.raises(ValueError, match="keeps no trace"):
            batch.result()
    assert sizes[0] == sizes[1]


def test_the_sensor_chain_converts_the_same_with_given_noise():
    chain = SensorChain(noise_lsb=1.0, rng=np.random.default_rng(2))
    temps = np.linspace(20.0, 300.0, 50)
    ticks = np.zeros(50, dtype=np.int64)
    drawn = chain.convert(temps, ticks)
    given = SensorChain().convert_with(temps, ticks, 1.0 * np.random.default_rng(2).standard_normal(50))
    np.testing.assert_array_equal(drawn, given)


def test_noisy_lanes_take_the_shortcut_to_the_same_counts():
    """Holding at the target, a noisy lane's samples mostly lie in one count: the compiled kernel then
    reads each noisy count off the chord's line (computing a sample only near an integer); the numpy
    lanes compute every sample. Same readings, bit for bit, over a long hold at several noise levels."""
    rng = np.random.default_rng(9)
    gains = [PidGains(*map(float, g)) for g in rng.uniform([10, 0.2, 50], [30, 1.5, 200], (9, 3))]
    noise, seeds = [0.3, 1.0, 3.0] * 3, [1] * 3 + [2] * 3 + [3] * 3
    runs = [_batch("hotend_cartridge", gains, 400.0, kernel=kernel, noise_lsb=noise, seed=seeds)
            for kernel in KERNELS]
    np.testing.assert_array_equal(runs[0].result().hotend.measured_c, runs[1].result().hotend.measured_c)
    np.testing.assert_array_equal(runs[0].result().hotend.duty, runs[1].result().hotend.duty)
