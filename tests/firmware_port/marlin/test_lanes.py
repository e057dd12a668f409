"""The vectorised firmware equals the scalar firmware, lane by lane; the compiled kernel equals both."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tests.helpers.near_half import value_near_half

from firmware_port.marlin.lanes import HotendLanes, PidLanes, div_round, lookup_q5, trunc_c
from firmware_port.marlin.softpwm import SoftPwm
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX
from firmware_port.marlin.pid import KD_Q16, KI_Q24, KP_Q12, PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND, PidFixed, PidGains
from firmware_port.fixed import div_round as scalar_div_round
from firmware_port.thermistor import B3950, B3950_TABLE, KLIPPER_SENSORS, MAX_RAW_THERMISTOR_VALUE, Divider
from twin.adc_table import adc_edges_c
from twin.adc_table import convert as adc_convert
from twin.batch import BatchTwin
from twin import batch_kernel
from twin.batch_kernel import KERNEL_ENV, KERNELS, default_kernel
from twin.engine import Twin
from twin.plants import make_plant
from twin.sensor import SensorChain

gains_st = st.builds(PidGains, kp=st.floats(0.0, KP_MAX), ki=st.floats(0.0, KI_MAX), kd=st.floats(0.0, KD_MAX))


def test_lookup_equals_the_scalar_lookup_on_every_raw_value():
    raw = np.arange(MAX_RAW_THERMISTOR_VALUE + 1)
    expected = [B3950_TABLE.lookup_q5(int(r)) for r in raw]
    assert lookup_q5(B3950_TABLE, raw).tolist() == expected


@given(st.lists(st.integers(-(1 << 40), 1 << 40), min_size=1, max_size=50), st.integers(1, 1 << 20))
def test_div_round_and_trunc_equal_the_scalar_helpers(values, divisor):
    a = np.array(values, dtype=np.int64)
    assert div_round(a, divisor).tolist() == [scalar_div_round(v, divisor) for v in values]
    small = np.clip(a, -(1 << 15), (1 << 15) - 1)
    assert trunc_c(small).tolist() == [int(v / 32) for v in small.tolist()]


@given(
    st.lists(gains_st, min_size=1, max_size=6),
    st.sampled_from([PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND]),
    st.lists(st.tuples(st.integers(0, 275), st.integers(0, MAX_RAW_THERMISTOR_VALUE)), min_size=1, max_size=60),
    st.randoms(use_true_random=False),
)
def test_pid_lanes_equal_scalar_pids(gains, mode, steps, rnd):
    """Same gains, same temperatures, same targets: the same Q.8 outputs and state, every step.
    Lanes see different readings (each a random raw value) and random inactive steps."""
    lanes = PidLanes(gains, mode)
    scalars = [PidFixed(g, mode) for g in gains]
    for target, raw in steps:
        temps = [B3950_TABLE.lookup_q5(max(0, raw - rnd.randint(0, 400))) for _ in gains]
        active = [rnd.random() < 0.9 for _ in gains]
        out = lanes.update_q8(np.array(temps, dtype=np.int64), target, np.array(active))
        for k, pid in enumerate(scalars):
            expected = pid.update_q8(temps[k], target) if active[k] else 0
            assert out[k] == expected
            assert (lanes.i_sum_q5[k], lanes.d_term_q8[k], lanes.prev_q5[k]) == (pid.i_sum_q5, pid.d_term_q8, pid.prev_q5)


@given(st.lists(st.tuples(st.integers(-(2**20), 2**20), st.integers(-2, 2), st.sampled_from(range(3))), min_size=1,
                max_size=8), gains_st)
def test_pid_lanes_scale_gains_as_the_scalar_pid(near_halves, other):
    """Each lane's integer constants are PidFixed's, also for gains whose scaled value lies on or next to a
    half (where a float product alone could round the other way) and for zero or negative Ki."""
    gains = [other, PidGains(other.kp, 0.0, other.kd), PidGains(other.kp, -abs(other.ki), other.kd)]
    for k, nudge, term in near_halves:
        value = value_near_half(k, nudge, (KP_Q12, KI_Q24, KD_Q16)[term].exact)
        top = (KP_MAX, KI_MAX, KD_MAX)[term]
        values = [other.kp, other.ki, other.kd]
        values[term] = min(max(value, -top), top)
        gains.append(PidGains(*values))
    lanes = PidLanes(gains)
    for k, g in enumerate(gains):
        pid = PidFixed(g)
        assert (lanes.kp_q12[k], lanes.ki_q24[k], lanes.kd_q16[k], lanes.i_max_q5[k]) == \
            (pid.kp_q12, pid.ki_q24, pid.kd_q16, pid.i_max_q5)


@given(
    st.integers(1, 127),
    st.lists(st.tuples(st.integers(0, 127), st.integers(0, 127), st.booleans()), min_size=1, max_size=8),
    st.integers(1, 300),
)
def test_pulses_equal_the_scalar_soft_pwm_waveform(pwm_count, lanes_state, n_ticks):
    lanes = HotendLanes([PidGains(1, 1, 1)] * len(lanes_state))
    lanes.pwm_count = pwm_count
    lanes.count = np.array([c for c, _, _ in lanes_state])
    lanes.amount = np.array([a for _, a, _ in lanes_state])
    lanes.pins = np.array([p for _, _, p in lanes_state])
    pulses = lanes.pulses(n_ticks)
    for k, (count, amount, pin) in enumerate(lanes_state):
        pwm = SoftPwm(1)
        pwm.pwm_count, pwm.count, pwm.amount, pwm.pins = pwm_count, [count], [amount], [pin]
        expected = pwm.waveform(0, n_ticks)
        got = np.zeros(n_ticks, bool)
        for alpha, beta in pulses:
            got[alpha : np.broadcast_to(beta, len(lanes_state))[k]] = True
        assert got.tolist() == expected.tolist()


# -- the batch twin's ADC table and compiled kernel ---------------------------------------------

def _ulp_window(edges_c: np.ndarray, half_width: int) -> np.ndarray:
    """Every double within ``half_width`` ulps of every finite edge."""
    steps = np.arange(-half_width, half_width + 1)
    return (edges_c[1:].view(np.int64)[:, None] + steps).view(np.float64).ravel()


@pytest.mark.parametrize("part", [B3950, KLIPPER_SENSORS["Honeywell 100K 135-104LAG-J01"]])
def test_adc_table_equals_the_sensor_chain_around_every_edge(part):
    """The only doubles where a table of edges could disagree with floor(1024 R / (R + Rp)) are
    next to an edge (where a rounding wobble of exp could make the float count non-monotone)."""
    edges = adc_edges_c(Divider(part))
    temps = _ulp_window(edges, 64)
    assert adc_convert(edges, temps).tolist() == SensorChain(Divider(part)).convert(temps, np.zeros(1, int)).tolist()


def test_a_steinhart_hart_part_has_no_table_and_the_batch_converts_each_sample():
    """Cardano's formula wobbles too far from the edges for a table; both kernels then convert
    every sample through the chain and still agree."""
    part = KLIPPER_SENSORS["ATC Semitec 104GT-2"]
    assert adc_edges_c(Divider(part)) is None
    runs = [_run_batch(kernel, "hotend", 25.0, [PidGains(22.2, 1.08, 114.0)], PREV_TEMP_EVERY_SAMPLE,
                       [(0.0, 200)], 20.0, SensorChain(Divider(part))) for kernel in KERNELS]
    _assert_same_batches(*runs)


@given(st.lists(st.floats(-100.0, 600.0), min_size=1, max_size=50))
def test_adc_table_equals_the_sensor_chain(temps):
    edges = adc_edges_c(Divider())
    temps = np.array(temps)
    assert adc_convert(edges, temps).tolist() == SensorChain().convert(temps, np.zeros(1, int)).tolist()


def _run_batch(kernel, preset, initial_c, gains, mode, events, duration_s, sensor=None):
    batch = BatchTwin(make_plant(preset, initial_c=initial_c), gains, prev_temp_mode=mode, kernel=kernel,
                      sensor=sensor)
    for at_s, target_c in events:
        batch.schedule(at_s, lambda b, t=target_c: b.set_target(t))
    batch.run_until(duration_s)
    return batch


LANE_STATE = ("amount", "count", "pins", "temp_q5", "halted", "trip_code", "runaway_state", "runaway_timer_ms",
              "watch_target_c", "watch_next_ms")
PID_STATE = ("i_sum_q5", "d_term_q8", "prev_q5", "reset_pending")


def _assert_same_batches(a: BatchTwin, b: BatchTwin) -> None:
    """Every record and every piece of state, bit for bit."""
    ra, rb = a.result().hotend, b.result().hotend
    for column in ("t_s", "measured_c", "block_c", "sensor_c", "duty"):
        assert np.array_equal(getattr(ra, column), getattr(rb, column)), column
    assert np.array_equal(a.x, b.x)
    for name in LANE_STATE:
        assert np.array_equal(getattr(a.lanes, name), getattr(b.lanes, name)), name
    for name in PID_STATE:
        assert np.array_equal(getattr(a.lanes.control, name), getattr(b.lanes.control, name)), name
    # the ADC's running sums per lane (the numpy path's AdcSequencer resets them to a scalar 0)
    assert np.array_equal(*(np.broadcast_to(t.lanes.adc.acc[0], t.n_lanes) for t in (a, b)))
    assert (a.lanes.adc.phase, a.lanes.adc.temp_count, a.lanes.pwm_count, a.lanes.ticks, a.tick) == \
        (b.lanes.adc.phase, b.lanes.adc.temp_count, b.lanes.pwm_count, b.lanes.ticks, b.tick)


@settings(max_examples=25)
@given(
    st.lists(gains_st | st.just(PidGains(0.0, 0.0, 0.0)), min_size=1, max_size=5),
    st.sampled_from([PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND]),
    st.sampled_from(["hotend", "hotend_cartridge"]),
    st.sampled_from([0.0, 25.0, 205.0, 290.0]),
    st.lists(st.tuples(st.floats(0.0, 80.0), st.sampled_from([0, 150, 210, 260, 300])), min_size=1, max_size=4),
    st.floats(1.0, 90.0),
)
@pytest.mark.slow
def test_kernel_equals_numpy_lanes(gains, mode, preset, initial_c, events, duration_s):
    """The compiled loop and the numpy lanes: same records and state, bit for bit, through target
    changes at any tick (periods of every length), protection trips (MINTEMP from cold, MAXTEMP
    from hot, heating failed with zero gains) and both prev-temperature modes. Without numba the
    kernel runs as plain Python: the same code, checked all the same."""
    runs = [_run_batch(kernel, preset, initial_c, gains, mode, events, duration_s) for kernel in KERNELS]
    _assert_same_batches(*runs)


@pytest.mark.parametrize("initial_c, target_c, trips", [
    (205.0, 214, ["", "Heating failed"]),  # in band from the start: zero gains give no heat
    (290.0, 210, ["MAXTEMP triggered"] * 2),
    (0.0, 210, ["MINTEMP triggered"] * 2),
])
def test_kernel_trips_as_the_numpy_lanes(initial_c, target_c, trips):
    """The protection trips these lanes, and both kernels halt the same lanes at the same reading."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(0.0, 0.0, 0.0)]
    runs = {kernel: _run_batch(kernel, "hotend", initial_c, gains, PREV_TEMP_EVERY_SAMPLE, [(1.0, target_c)], 60.0)
            for kernel in KERNELS}
    _assert_same_batches(*runs.values())
    assert runs["numba"].lanes.trip.tolist() == trips


@pytest.mark.parametrize("kernel", KERNELS)
def test_every_kernel_equals_scalar_twins(kernel):
    """Each lane of either kernel is the scalar firmware on its own twin: same readings and duty."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(40.0, 3.0, 60.0)]
    batch = _run_batch(kernel, "hotend_cartridge", 25.0, gains, PREV_TEMP_EVERY_SAMPLE, [(0.5, 210)], 120.0)
    for lane, g in enumerate(gains):
        twin = Twin([make_plant("hotend_cartridge")], "pid")
        twin.board.hotend.controller.set_gains(g)
        twin.schedule(0.5, lambda tw: tw.board.set_target(0, 210))
        twin.run_until(120.0)
        hotend = twin.result().hotend
        lanes = batch.result().hotend
        assert np.array_equal(hotend.measured_c, lanes.measured_c[:, lane])
        assert np.array_equal(hotend.duty, lanes.duty[:, lane])


def test_a_noisy_sensor_gives_the_same_numbers_on_either_kernel():
    """A chain with noise lends its generator as the lanes' one stream (common random numbers): both
    kernels draw it in the same order, so they agree bit for bit, and lanes with the same gains read
    the same noisy values."""
    runs = [_run_batch(kernel, "hotend", 25.0, [PidGains(22.2, 1.08, 114.0)] * 2 + [PidGains(40.0, 3.0, 60.0)],
                       PREV_TEMP_EVERY_SAMPLE, [(0.0, 210)], 30.0,
                       SensorChain(noise_lsb=1.0, rng=np.random.default_rng(5)))
            for kernel in KERNELS]
    _assert_same_batches(*runs)
    noisy = runs[0].result().hotend.measured_c
    assert np.array_equal(noisy[:, 0], noisy[:, 1])
    quiet = _run_batch("numba", "hotend", 25.0, [PidGains(22.2, 1.08, 114.0)], PREV_TEMP_EVERY_SAMPLE, [(0.0, 210)],
                       30.0)
    assert not np.array_equal(noisy[:, 0], quiet.result().hotend.measured_c[:, 0])  # the noise is there


def test_kernel_choice_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv(KERNEL_ENV, "numpy")
    assert BatchTwin(make_plant("hotend"), [PidGains(1, 1, 1)]).kernel == "numpy"
    monkeypatch.setenv(KERNEL_ENV, "cuda")
    with pytest.raises(ValueError, match=f"{KERNEL_ENV}='cuda'"):
        default_kernel()


def test_asking_for_numba_without_it_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(batch_kernel, "numba", None)
    monkeypatch.setenv(KERNEL_ENV, "numba")
    with pytest.raises(ValueError, match="numba is not installed"):
        default_kernel()
