"""Properties 2-4: the fixed-point PID never overflows, agrees with float32, keeps its clamp."""

from fractions import Fraction

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from tests.helpers.near_half import value_near_half

from firmware_port.marlin.pid import (
    D_RAW_LIMIT_Q8,
    D_SHIFT,
    I_SHIFT,
    OUT_FRAC_BITS,
    PREV_TEMP_EVERY_SAMPLE,
    PREV_TEMP_IN_BAND,
    PidFixed,
    float_error_bound_counts,
    q_scaled,
)
from firmware_port.marlin.constants import PID_DT_S
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX, PidGains
from firmware_port.marlin.pid_float import PidFloat
from firmware_port.thermistor import B3950_TABLE, MAX_RAW_THERMISTOR_VALUE

gains_st = st.builds(  # M301 stores negative gains too (Marlin's gcode/config/M301.cpp)
    PidGains,
    kp=st.floats(-KP_MAX, KP_MAX),
    ki=st.floats(-KI_MAX, KI_MAX),
    kd=st.floats(-KD_MAX, KD_MAX),
)
realistic_gains_st = st.builds(
    PidGains,
    kp=st.floats(1.0, 200.0),
    ki=st.floats(0.01, 20.0),
    kd=st.floats(0.0, 2000.0),
)
signed_gains_st = st.builds(  # what a mistyped M301 P-5 gives: realistic magnitudes, any sign
    PidGains,
    kp=st.floats(-200.0, 200.0),
    ki=st.floats(-20.0, 20.0),
    kd=st.floats(-2000.0, 2000.0),
)
mode_st = st.sampled_from([PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND])
raw_seq_st = st.lists(st.integers(0, MAX_RAW_THERMISTOR_VALUE), min_size=1, max_size=120)
target_st = st.integers(0, 275)


@given(gains_st, mode_st, raw_seq_st, st.lists(target_st, min_size=1, max_size=8))
def test_no_overflow_over_the_full_domain_and_output_in_range(gains, mode, raws, targets):
    """Any gains in the documented ranges, any raw reading, any targets: every checked
    intermediate fits its declared width (else OverflowError) and the output is 0..255."""
    pid = PidFixed(gains, mode)
    for k, raw in enumerate(raws):
        out = pid.update(B3950_TABLE.lookup_q5(raw), targets[k % len(targets)])
        assert 0 <= out <= 255
        assert -(1 << 31) <= pid.d_term_q8 < 1 << 31
        assert -(1 << 15) <= pid.prev_q5 < 1 << 15


@given(gains_st, mode_st, st.lists(st.integers(-(1 << 15), (1 << 15) - 1), min_size=1, max_size=80), target_st)
def test_no_overflow_for_any_int16_temperature(gains, mode, temps_q5, target):
    pid = PidFixed(gains, mode)
    for t in temps_q5:
        assert 0 <= pid.update(t, target) <= 255


@given(gains_st, mode_st, raw_seq_st, target_st)
def test_integral_clamp_invariant_after_every_step(gains, mode, raws, target):
    """0 <= i_sum <= i_max and Ki * i_sum <= PID_MAX (in the firmware's own integers); with a
    negative Ki the ceiling is negative and constrain() gives 0 or the ceiling, a term >= PID_MAX."""
    pid = PidFixed(gains, mode)
    for raw in raws:
        pid.update(B3950_TABLE.lookup_q5(raw), target)
        if pid.ki_q24 >= 0:
            assert 0 <= pid.i_sum_q5 <= pid.i_max_q5
            assert pid.ki_q24 * pid.i_sum_q5 <= 255 << I_SHIFT + OUT_FRAC_BITS
        else:
            assert pid.i_sum_q5 in (0, pid.i_max_q5) and pid.i_max_q5 < 0
            assert pid.ki_q24 * pid.i_sum_q5 >= 0


def _walk(start_q5, steps_q5):
    temps, t = [], start_q5
    for s in steps_q5:
        t = max(-27 * 32, min(938 * 32, t + s))
        temps.append(t)
    return temps


@given(
    st.one_of(realistic_gains_st, signed_gains_st),
    mode_st,
    st.integers(150 * 32, 260 * 32),
    st.lists(st.integers(-96, 96), min_size=1, max_size=150),
    st.integers(160, 260),
)
def test_fixed_agrees_with_float32_reference(gains, mode, start_q5, steps_q5, target):
    """|fixed - float| on the 0..255 output (before truncation) stays within the derived bound;
    the truncated integer outputs differ by at most one count."""
    temps = _walk(start_q5, steps_q5)
    fixed, ref = PidFixed(gains, mode), PidFloat(gains, mode)
    # The largest derivative input the sequence produces, and no saturation of it.
    prev, max_dtemp_q5 = 0, 0
    for t in temps:
        in_band = abs(target * 32 - t) <= 320
        if in_band:
            max_dtemp_q5 = max(max_dtemp_q5, abs(prev - t))
        if mode == PREV_TEMP_EVERY_SAMPLE or in_band:
            prev = t
    assume(fixed.kd_q16 * max_dtemp_q5 >> D_SHIFT <= D_RAW_LIMIT_Q8)
    bound = float_error_bound_counts(gains, max_dtemp_q5 / 32)
    for t in temps:
        a = fixed.update_q8(t, target) / 256
        b = float(ref.update_f32(t, target))
        assert abs(a - b) <= bound, (a, b, bound)
        assert abs(int(a) - int(b)) <= 1


def test_the_bound_is_small_for_marlin_defaults():
    # a hotend moves well under 2 C per 0.164 s sample
    assert float_error_bound_counts(PidGains(22.2, 1.08, 114.0), 2.0) < 0.15
    assert float_error_bound_counts(PidGains(10.0, 0.023, 305.4), 2.0) < 0.15


def test_bang_outside_the_functional_range_and_zero_target():
    pid = PidFixed()
    assert pid.update(100 * 32, 210) == 255
    assert pid.update(221 * 32, 210) == 0
    assert pid.update(25 * 32, 0) == 0


def test_stale_previous_temperature_kick_of_marlin_2_1():
    """2.1.x keeps T_prev = 0 until the first in-band sample: a huge negative D kick."""
    fresh, stale = PidFixed(prev_temp_mode=PREV_TEMP_EVERY_SAMPLE), PidFixed(prev_temp_mode=PREV_TEMP_IN_BAND)
    for t_c in range(150, 191):
        fresh.update(t_c * 32, 200)
        stale.update(t_c * 32, 200)
    assert stale.update(191 * 32, 200) == 0  # 0.05 * 696 * (0 - 191) ~ -6650 counts
    assert stale.d_term_q8 < -6000 * 256
    assert fresh.update(191 * 32, 200) > 100


def test_gains_outside_the_documented_range_are_rejected():
    with pytest.raises(ValueError, match="kd"):
        PidGains(10, 1, KD_MAX + 1)


# The scalings the PID and the fuzzy-PID use: (scale, fraction bits).
SCALINGS = [(Fraction(1), 12), (PID_DT_S, 24), (1 / PID_DT_S, 16), (1 / PID_DT_S, 12)]


def exact_q(value: float, scale: Fraction, frac_bits: int) -> int:
    """The definition: the decimal the user typed (repr), scaled exactly, rounded half to even."""
    return round(Fraction(repr(float(value))) * scale * (1 << frac_bits))


@given(value=st.floats(allow_nan=False, allow_infinity=False, min_value=-1e12, max_value=1e12),
       scaling=st.sampled_from(SCALINGS))
def test_q_scaled_is_the_exact_rounding_of_the_decimal(value, scaling):
    assert q_scaled(value, *scaling) == exact_q(value, *scaling)


@given(k=st.integers(-(2**40), 2**40), nudge=st.integers(-3, 3), scaling=st.sampled_from(SCALINGS))
def test_q_scaled_is_exact_next_to_a_half(k, nudge, scaling):
    """Values whose scaled product lies on or a few ulps from k + 1/2, where a float product alone
    could round the wrong way: the exact path decides."""
    scale, bits = scaling
    value = value_near_half(k, nudge, scale * (1 << bits))
    assert q_scaled(value, scale, bits) == exact_q(value, scale, bits)


def test_q_scaled_rounds_an_exact_half_to_even():
    assert q_scaled(2.5, Fraction(1), 0) == 2 and q_scaled(3.5, Fraction(1), 0) == 4
    assert q_scaled(-2.5, Fraction(1), 0) == -2
