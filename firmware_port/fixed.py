"""Integer arithmetic with AVR (avr-gcc) semantics.

Python integers never overflow; the ATmega328 does. Every helper here says whether it
*wraps* (two's complement, what C does on overflow of a fixed-width type) or *saturates*
(what a careful firmware does on purpose), and how it rounds. The firmware code calls only
these, so a reader can see each width and each rounding decision.

Q-format: a value ``x`` stored as ``Qm.f`` is the integer ``round(x * 2**f)``.
"""

from __future__ import annotations

INT16_MIN, INT16_MAX = -(1 << 15), (1 << 15) - 1
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1
UINT8_MAX = (1 << 8) - 1
UINT16_MAX = (1 << 16) - 1
UINT32_MAX = (1 << 32) - 1


def wrap_u8(x: int) -> int:
    """uint8_t assignment: keep the low 8 bits."""
    return x & UINT8_MAX


def wrap_u16(x: int) -> int:
    """uint16_t assignment: keep the low 16 bits."""
    return x & UINT16_MAX


def wrap_u32(x: int) -> int:
    """uint32_t assignment: keep the low 32 bits."""
    return x & UINT32_MAX


def wrap_s16(x: int) -> int:
    """int16_t assignment: two's complement wrap of the low 16 bits."""
    return ((x + (1 << 15)) & UINT16_MAX) - (1 << 15)


def wrap_s32(x: int) -> int:
    """int32_t assignment: two's complement wrap of the low 32 bits."""
    return ((x + (1 << 31)) & UINT32_MAX) - (1 << 31)


INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1


def checked_s32(x: int) -> int:
    """A value the firmware computes in int32 and has proven cannot overflow; raises if it would.

    Used on every product and sum in the control path, so a broken bound fails loudly in the
    property tests instead of wrapping silently as it would on the MCU.
    """
    if not INT32_MIN <= x <= INT32_MAX:
        raise OverflowError(f"{x} does not fit int32")
    return x


def checked_s64(x: int) -> int:
    """Like ``checked_s32`` for an int64 (avr-gcc ``long long``) intermediate."""
    if not INT64_MIN <= x <= INT64_MAX:
        raise OverflowError(f"{x} does not fit int64")
    return x


def clamp(x: int, lo: int, hi: int) -> int:
    """Saturate ``x`` into ``[lo, hi]`` (Marlin's ``constrain``)."""
    return lo if x < lo else hi if x > hi else x


def sat_s16(x: int) -> int:
    """Saturate into int16_t."""
    return clamp(x, INT16_MIN, INT16_MAX)


def sat_s32(x: int) -> int:
    """Saturate into int32_t."""
    return clamp(x, INT32_MIN, INT32_MAX)


def c_div(a: int, b: int) -> int:
    """C integer division: the quotient truncated toward zero (Python's ``//`` floors)."""
    if b == 0:
        raise ZeroDivisionError("integer division by zero")
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b > 0) else -q


def div_round(a: int, b: int) -> int:
    """Division rounded to nearest, halves away from zero: ``(a + sign*b/2) / b`` in C."""
    if b < 0:
        a, b = -a, -b
    half = b // 2
    return c_div(a + half, b) if a >= 0 else c_div(a - half, b)


def shr_round(x: int, n: int) -> int:
    """Arithmetic shift right by ``n`` with rounding: ``(x + (1 << (n-1))) >> n``.

    avr-gcc's ``>>`` on a signed value is arithmetic (floors), so adding half first rounds to
    nearest with halves toward +infinity. ``n == 0`` returns ``x``.
    """
    if n == 0:
        return x
    return (x + (1 << (n - 1))) >> n


def q_mul(a: int, b: int, frac_bits: int) -> int:
    """Product of two Q numbers, dropping ``frac_bits`` with ``shr_round`` rounding.

    The caller guarantees (and the property tests check) that ``a * b`` fits the width the
    firmware computes it in; this helper does not wrap, so a violated bound shows up as a
    value outside the declared range instead of a silently wrapped one.
    """
    return shr_round(a * b, frac_bits)


def to_q(x: float, frac_bits: int) -> int:
    """Configuration-time conversion of a decimal setting to Q format, rounded to nearest."""
    return int(round(x * (1 << frac_bits)))
