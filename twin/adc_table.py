"""A noiseless sensor chain's ADC as a table of switching temperatures, for batch kernels.

``SensorChain.convert`` is ``floor(1024 R / (R + Rp))`` of the sensor node's temperature: an
exponential, a division and a floor per sample, the largest cost of a batch twin. That count
falls as the temperature rises, so it is fixed by the 1023 temperatures where it steps down:
``edges_c[k]`` (k = 1..1023) is the lowest double at which the chain's own float evaluation
gives a count below k, found by bisection over the doubles with ``convert`` itself. Then the
count of T is the number of edges above T: comparisons only, the same in numpy and in a compiled
loop. It equals ``convert`` wherever that float evaluation falls monotonically. For a beta part
(one exponential, correct to about an ulp) a wobble can only show within a few ulps of an edge;
tests/firmware_port/marlin/test_lanes.py checks every double within 64 ulps of every edge, and random temperatures
elsewhere. A full Steinhart-Hart part goes through Cardano's formula, whose cancellation wobbles
far wider (the Semitec 104GT-2 disagrees 4 ulps from an edge): no table for those, the batch
converts sample by sample.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from firmware_port.thermistor import ADC_MAX, Divider
from twin.sensor import SensorChain

COLDEST_C, HOTTEST_C = -200.0, 1000.0  # brackets: every NTC part reads 1023 and 0 there
SIGN_MASK = np.int64(0x7FFF_FFFF_FFFF_FFFF)
INTERPOLATION_MARGIN = 1e-9  # counts: far above the rounding of a value near 1024 (2e-13)


def _ordered(temps_c: np.ndarray) -> np.ndarray:
    """Doubles to int64 keys in the same order (adjacent doubles: adjacent keys)."""
    bits = temps_c.view(np.int64)
    return np.where(bits < 0, -(bits & SIGN_MASK), bits)


def _from_ordered(keys: np.ndarray) -> np.ndarray:
    bits = np.where(keys < 0, (-keys) | ~SIGN_MASK, keys)
    return bits.view(np.float64)


@functools.lru_cache(maxsize=8)
def adc_edges_c(divider: Divider) -> np.ndarray | None:
    """(ADC_MAX + 1,) float64: +inf, then the temperature below which the count is >= k, k = 1..ADC_MAX.

    None for a part that is not a beta model (see the module's docstring).
    """
    if divider.part.c3:
        return None
    chain = SensorChain(divider)
    return edges_of(lambda temps_c: chain.convert(temps_c, np.zeros(len(temps_c), dtype=np.int64)), ADC_MAX)


def edges_of(count: Callable[[np.ndarray], np.ndarray], adc_max: int, hottest_c: float = HOTTEST_C) -> np.ndarray:
    """The switching temperatures of a falling count function of temperature (any converter's):
    +inf, then for k = 1..adc_max the lowest double at which ``count`` is below k (bisection)."""
    k = np.arange(1, adc_max + 1)
    lo = _ordered(np.full(adc_max, COLDEST_C))  # count(lo) >= k
    hi = _ordered(np.full(adc_max, hottest_c))  # count(hi) < k
    if count(np.array([COLDEST_C]))[0] != adc_max or count(np.array([hottest_c]))[0] != 0:
        raise ValueError(f"sensor chain does not span the ADC between {COLDEST_C} and {hottest_c} C")
    while np.any(hi > lo + 1):
        mid = (lo >> 1) + (hi >> 1) + (lo & hi & 1)  # the midpoint without overflowing int64
        above = count(_from_ordered(mid)) >= k
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    edges = np.concatenate(([np.inf], _from_ordered(hi)))
    edges.flags.writeable = False
    return edges


@functools.lru_cache(maxsize=8)
def noise_interpolation(divider: Divider) -> tuple[np.ndarray, np.ndarray] | None:
    """For a noisy chain: the analog value between two edges as a straight line, and how far off it can be.

    Between ``edges[c + 1]`` and ``edges[c]`` the chain's analog value runs from c + 1 down to c;
    ``c + (edges[c] - T) * slope[c]`` approximates it within ``bound[c]`` (twice the largest error
    over 65 points of the interval, plus 1e-9: the error of a line through a smooth function's ends
    is a smooth bump, which 65 points resolve). A noisy count ``floor(analog + noise)`` is then
    decided by the line unless the noisy value lies within the bound of an integer; only then must
    the analog value itself be computed (twin/batch_kernel.py). Counts 0 and ADC_MAX (open
    intervals) have no line: bound +inf. None where ``adc_edges_c`` is None.
    """
    edges = adc_edges_c(divider)
    if edges is None:
        return None
    chain = SensorChain(divider)
    c = np.arange(1, ADC_MAX)
    hi, lo = edges[c], edges[c + 1]
    slope = 1.0 / (hi - lo)
    temps = lo + (hi - lo) * np.linspace(0.0, 1.0, 65)[:, None]
    line = c + (hi - temps) * slope
    error = np.abs(line - chain.analog(temps, np.zeros(1, dtype=np.int64))).max(axis=0)
    slopes, bounds = np.zeros(ADC_MAX + 1), np.full(ADC_MAX + 1, np.inf)
    slopes[c], bounds[c] = slope, 2.0 * error + INTERPOLATION_MARGIN
    for table in (slopes, bounds):
        table.flags.writeable = False
    return slopes, bounds


def convert(edges_c: np.ndarray, temps_c: np.ndarray) -> np.ndarray:
    """ADC counts of temperatures (any shape): how many edges lie above each."""
    ascending = edges_c[:0:-1]
    return ADC_MAX - np.searchsorted(ascending, temps_c, side="right")
