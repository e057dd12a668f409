"""fixed.py's rounding on numpy int64 lanes (the batch's numpy path): the same integers, elementwise.

numpy's int64 shifts are arithmetic like avr-gcc's, and its ``//`` floors as Python's does, so each
helper gives, lane by lane, what its scalar namesake gives (tests/firmware_port/marlin/test_lanes.py).
"""

from __future__ import annotations

import numpy as np

from firmware_port.thermistor import TEMP_FRAC_BITS


def shr_round(x: np.ndarray, n: int) -> np.ndarray:
    """``fixed.shr_round`` on int64 lanes."""
    return (x + (1 << (n - 1))) >> n


def div_round(a: np.ndarray, b) -> np.ndarray:
    """``fixed.div_round`` on int64 lanes, positive divisor(s): nearest, halves away from zero."""
    half = b // 2
    return np.where(a >= 0, (a + half) // b, -((-a + half) // b))


def trunc_c(temp_q5: np.ndarray) -> np.ndarray:
    """celsius_q5 to celsius_t, truncated toward zero as C converts a float."""
    return np.where(temp_q5 >= 0, temp_q5 >> TEMP_FRAC_BITS, -((-temp_q5) >> TEMP_FRAC_BITS))
