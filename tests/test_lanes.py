"""The vectorised firmware equals the scalar firmware, lane by lane."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.marlin.lanes import HotendLanes, PidLanes, div_round, lookup_q5, trunc_c
from firmware_port.marlin.softpwm import SoftPwm
from firmware_port.marlin.pid import KD_MAX, KI_MAX, KP_MAX, PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND, PidFixed, PidGains
from firmware_port.fixed import div_round as scalar_div_round
from firmware_port.thermistor import B3950_TABLE, MAX_RAW_THERMISTOR_VALUE

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
