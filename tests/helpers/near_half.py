"""Gains whose scaled value lies on or next to a half: where a float product alone could round wrongly."""

from __future__ import annotations

import math
from fractions import Fraction


def value_near_half(k: int, nudge: int, factor: Fraction) -> float:
    """The float nearest (k + 1/2) / factor, moved ``nudge`` ulps (up when positive)."""
    value = float((k + Fraction(1, 2)) / factor)
    for _ in range(abs(nudge)):
        value = math.nextafter(value, math.inf if nudge > 0 else -math.inf)
    return value
