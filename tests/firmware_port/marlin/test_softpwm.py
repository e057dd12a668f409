"""Property 7: over any whole soft-PWM period the on-time equals the latched amount exactly."""

from hypothesis import given
from hypothesis import strategies as st

from firmware_port.marlin.constants import SOFT_PWM_PERIOD_TICKS
from firmware_port.marlin.softpwm import SoftPwm

# (tick at which the main loop writes, amount) pairs, in any order and timing
writes_st = st.lists(st.tuples(st.integers(0, 8 * SOFT_PWM_PERIOD_TICKS), st.integers(0, 127)), max_size=30)


def _run(writes, n_ticks):
    pwm = SoftPwm(1)
    by_tick = {}
    for tick, amount in writes:
        by_tick[tick] = amount
    pins, latched = [], []
    for tick in range(n_ticks):
        if tick in by_tick:
            pwm.set_amount(0, by_tick[tick])
        wrap = pwm.pwm_count >= SOFT_PWM_PERIOD_TICKS
        pwm.tick()
        pins.append(pwm.pins[0])
        if wrap:
            latched.append((tick, pwm.count[0]))
    return pins, latched


@given(writes_st)
def test_on_time_per_period_equals_the_latched_amount(writes):
    pins, latched = _run(writes, 10 * SOFT_PWM_PERIOD_TICKS)
    for start, amount in latched:
        period = pins[start : start + SOFT_PWM_PERIOD_TICKS]
        if len(period) == SOFT_PWM_PERIOD_TICKS:
            assert sum(period) == amount
            # one pulse at the start of the period: high for `amount` ticks, then low
            assert period == [True] * amount + [False] * (SOFT_PWM_PERIOD_TICKS - amount)


@given(writes_st)
def test_periods_are_127_ticks_and_the_first_wrap_is_at_tick_126(writes):
    _, latched = _run(writes, 6 * SOFT_PWM_PERIOD_TICKS)
    starts = [t for t, _ in latched]
    assert starts[0] == SOFT_PWM_PERIOD_TICKS - 1  # pwm_count starts at 1
    assert all(b - a == SOFT_PWM_PERIOD_TICKS for a, b in zip(starts, starts[1:]))


def test_a_new_amount_waits_for_the_next_period():
    pwm = SoftPwm(1)
    for _ in range(SOFT_PWM_PERIOD_TICKS):  # reach the first wrap with amount 0
        pwm.tick()
    pwm.set_amount(0, 127)
    pwm.tick()
    assert pwm.pins[0] is False


def test_all_off_drops_the_pins_at_once():
    pwm = SoftPwm(2)
    pwm.set_amount(0, 127)
    pwm.set_amount(1, 60)
    for _ in range(SOFT_PWM_PERIOD_TICKS):
        pwm.tick()
    assert pwm.pins == [True, True]
    pwm.all_off()
    assert pwm.pins == [False, False] and pwm.amount == [0, 0]


state_st = st.tuples(
    st.integers(1, SOFT_PWM_PERIOD_TICKS),  # pwm_count
    st.lists(st.integers(0, 127), min_size=2, max_size=2),  # latched counts
    st.lists(st.integers(0, 127), min_size=2, max_size=2),  # amounts
    st.lists(st.booleans(), min_size=2, max_size=2),  # pins
)


def _pwm_from(state):
    pwm = SoftPwm(2)
    pwm.pwm_count, counts, amounts, pins = state
    pwm.count, pwm.amount, pwm.pins = list(counts), list(amounts), list(pins)
    return pwm


@given(state_st, st.integers(0, 3 * SOFT_PWM_PERIOD_TICKS))
def test_waveform_and_skip_equal_tick_by_tick(state, n_ticks):
    """The fast engine's closed form: same pins at every tick and the same final state."""
    stepped, fast = _pwm_from(state), _pwm_from(state)
    expected = [[], []]
    for _ in range(n_ticks):
        stepped.tick()
        for ch in range(2):
            expected[ch].append(stepped.pins[ch])
    for ch in range(2):
        assert fast.waveform(ch, n_ticks).tolist() == expected[ch]
    fast.skip(n_ticks)
    assert (fast.pwm_count, fast.count, fast.pins) == (stepped.pwm_count, stepped.count, stepped.pins)
