"""Property 1: the integer helpers wrap, saturate, divide and round exactly like avr-gcc."""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port import fixed

big = st.integers(min_value=-(1 << 70), max_value=1 << 70)


@given(big)
def test_wrap_matches_twos_complement_casts(x):
    # numpy casts keep the low bits exactly as an AVR register assignment does.
    low64 = np.array(x & ((1 << 64) - 1), dtype=np.uint64)
    assert fixed.wrap_s16(x) == int(low64.astype(np.int16))
    assert fixed.wrap_s32(x) == int(low64.astype(np.int32))
    assert fixed.wrap_u8(x) == int(low64.astype(np.uint8))
    assert fixed.wrap_u16(x) == int(low64.astype(np.uint16))
    assert fixed.wrap_u32(x) == int(low64.astype(np.uint32))


@given(big)
def test_wrap_is_identity_inside_the_range_and_congruent_outside(x):
    for wrap, bits, signed in ((fixed.wrap_s16, 16, True), (fixed.wrap_s32, 32, True), (fixed.wrap_u8, 8, False)):
        w = wrap(x)
        lo = -(1 << (bits - 1)) if signed else 0
        assert lo <= w < lo + (1 << bits)
        assert (w - x) % (1 << bits) == 0


@given(big)
def test_saturation_clamps_to_the_type_limits(x):
    assert fixed.sat_s16(x) == min(max(x, -32768), 32767)
    assert fixed.sat_s32(x) == min(max(x, -(1 << 31)), (1 << 31) - 1)


@given(big, big.filter(lambda b: b != 0))
def test_c_div_truncates_toward_zero(a, b):
    q = fixed.c_div(a, b)
    assert abs(q) == abs(a) // abs(b)
    assert q == 0 or (q > 0) == ((a > 0) == (b > 0))
    # C's identity: a == (a/b)*b + a%b with |a%b| < |b| and a%b taking a's sign
    r = a - q * b
    assert abs(r) < abs(b) and (r == 0 or (r > 0) == (a > 0))


def test_c_div_by_zero_raises():
    with pytest.raises(ZeroDivisionError):
        fixed.c_div(1, 0)


@given(big, big.filter(lambda b: b != 0))
def test_div_round_is_nearest_with_halves_away_from_zero(a, b):
    exact = Fraction(a, b)
    q = fixed.div_round(a, b)
    assert abs(exact - q) <= Fraction(1, 2)
    if abs(exact - q) == Fraction(1, 2):
        assert abs(q) > abs(exact)


@given(big, st.integers(min_value=0, max_value=40))
def test_shr_round_is_nearest_with_halves_up(x, n):
    exact = Fraction(x, 1 << n)
    expected = x if n == 0 else int((exact + Fraction(1, 2)).__floor__())
    assert fixed.shr_round(x, n) == expected


@given(st.integers(-(1 << 20), 1 << 20), st.integers(-(1 << 20), 1 << 20), st.integers(0, 24))
def test_q_mul_rounds_the_exact_product(a, b, f):
    assert abs(Fraction(a * b, 1 << f) - fixed.q_mul(a, b, f)) <= Fraction(1, 2)


@given(big)
def test_checked_widths_accept_exactly_their_range(x):
    for check, bits in ((fixed.checked_s32, 32), (fixed.checked_s64, 64)):
        fits = -(1 << (bits - 1)) <= x < (1 << (bits - 1))
        if fits:
            assert check(x) == x
        else:
            with pytest.raises(OverflowError):
                check(x)


@given(st.floats(-1e4, 1e4), st.integers(0, 24))
def test_to_q_rounds_to_nearest(x, f):
    assert abs(fixed.to_q(x, f) - x * (1 << f)) <= 0.5 + 1e-9 * abs(x) * (1 << f)
