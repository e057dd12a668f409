"""NTC thermistors: the physics (beta, Steinhart-Hart) and the firmware's lookup table.

Two separate things live here, as on a real printer:
- the *physics* of a part (resistance <-> temperature), used by the twin's sensor model and to
  generate tables; floats are fine there;
- the *firmware table*: Marlin-style ``{raw, temperature}`` rows sorted by raw ascending, where
  raw is the sum of OVERSAMPLENR 10-bit samples (0..16368), looked up with an integer binary
  search and integer linear interpolation (Marlin's ``SCAN_THERMISTOR_TABLE``, minus the float).

Temperatures in the firmware are ``celsius_q5``: int16, Q10.5, i.e. 1/32 degC, range -1024..1023.97.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
import numpy as np

from firmware_port.fixed import INT16_MAX, INT16_MIN, div_round

KELVIN_OFFSET = 273.15
ADC_BITS = 10
ADC_COUNTS = 1 << ADC_BITS  # Marlin/createTemperatureLookupMarlin: adc = 1024 * R / (R + Rp)
ADC_MAX = ADC_COUNTS - 1
OVERSAMPLENR = 16  # Marlin module/thermistor/thermistors.h
RAW_MAX = ADC_MAX * OVERSAMPLENR  # 16368: 16 samples of 1023
MAX_RAW_THERMISTOR_VALUE = ADC_COUNTS * OVERSAMPLENR - 1  # 16383, where Marlin's MINTEMP scan starts
TEMP_FRAC_BITS = 5  # celsius_q5
TEMP_ONE = 1 << TEMP_FRAC_BITS


def c_to_q5(temp_c: float) -> int:
    """Degrees C to celsius_q5, rounded to nearest (configuration time only)."""
    return int(round(temp_c * TEMP_ONE))


def q5_to_c(temp_q5: int) -> float:
    """celsius_q5 to degrees C (exact)."""
    return temp_q5 / TEMP_ONE


@dataclass(frozen=True)
class SteinhartHart:
    """``1/T = c1 + c2*ln(R) + c3*ln(R)**3`` with T in kelvin (Klipper's form; beta: c3 = 0)."""

    c1: float
    c2: float
    c3: float

    @classmethod
    def from_beta(cls, r25_ohm: float, beta_k: float, t25_c: float = 25.0) -> SteinhartHart:
        """Beta model ``1/T = 1/T0 + ln(R/R0)/B`` as Steinhart-Hart coefficients."""
        c2 = 1.0 / beta_k
        return cls(1.0 / (t25_c + KELVIN_OFFSET) - c2 * math.log(r25_ohm), c2, 0.0)

    @classmethod
    def from_points(cls, points: tuple[tuple[float, float], ...]) -> SteinhartHart:
        """Solve exactly through three (temp_c, resistance_ohm) points, as Klipper does."""
        if len(points) != 3:
            raise ValueError("Steinhart-Hart needs exactly three (temp_c, resistance_ohm) points")
        a = np.array([[1.0, math.log(r), math.log(r) ** 3] for _, r in points])
        b = np.array([1.0 / (t + KELVIN_OFFSET) for t, _ in points])
        c1, c2, c3 = np.linalg.solve(a, b)
        return cls(float(c1), float(c2), float(c3))

    def temp_c(self, resistance_ohm: float) -> float:
        """Temperature of the part at a resistance."""
        ln_r = math.log(resistance_ohm)
        return 1.0 / (self.c1 + self.c2 * ln_r + self.c3 * ln_r**3) - KELVIN_OFFSET

    def resistance_ohm(self, temp_c):
        """Resistance of the part at a temperature (closed form for beta, Cardano otherwise).

        Accepts a float or a numpy array (the twin converts a run of samples at once).
        """
        inv_t = 1.0 / (np.asarray(temp_c, dtype=float) + KELVIN_OFFSET)
        if self.c3 == 0.0:
            return np.exp((inv_t - self.c1) / self.c2)
        # c3*x^3 + c2*x + (c1 - 1/T) = 0: one real root where c2, c3 > 0 (Cardano)
        p = self.c2 / self.c3
        q = (self.c1 - inv_t) / self.c3
        if self.c3 > 0.0:
            disc = np.sqrt(q * q / 4.0 + p**3 / 27.0)
            return np.exp(np.cbrt(-q / 2.0 + disc) + np.cbrt(-q / 2.0 - disc))
        # c3 < 0 (a curve through three points can bend that way): three real roots; the part's is the one
        # nearest the beta curve's ln R (the trigonometric form of the roots)
        beta_ln_r = (inv_t - self.c1) / self.c2
        arg = np.clip(1.5 * q / p * np.sqrt(-3.0 / p), -1.0, 1.0)
        roots = [2.0 * np.sqrt(-p / 3.0) * np.cos(np.arccos(arg) / 3.0 - 2.0 * np.pi * k / 3.0) for k in range(3)]
        nearest = np.argmin(np.abs(np.array(roots) - beta_ln_r), axis=0)
        return np.exp(np.choose(nearest, roots))


# Klipper's built-in sensors (klippy/extras/temperature_sensors.cfg): (temp_c, resistance_ohm).
KLIPPER_SENSORS: dict[str, SteinhartHart] = {
    "EPCOS 100K B57560G104F": SteinhartHart.from_points(((25, 100000), (150, 1641.9), (250, 226.15))),
    "ATC Semitec 104GT-2": SteinhartHart.from_points(((20, 126800), (150, 1360), (300, 80.65))),
    "ATC Semitec 104NT-4-R025H42G": SteinhartHart.from_points(((25, 100000), (160, 1074), (300, 82.78))),
    "Generic 3950": SteinhartHart.from_points(((25, 100000), (150, 1770), (250, 230))),
    "SliceEngineering 450": SteinhartHart.from_points(((25, 500000), (200, 3734), (400, 240))),
    "TDK NTCG104LH104JT1": SteinhartHart.from_points(((25, 100000), (50, 31230), (125, 2066))),
    "Honeywell 100K 135-104LAG-J01": SteinhartHart.from_beta(100000, 3974),
    "NTC 100K MGB18-104F39050L32": SteinhartHart.from_beta(100000, 4100),
}

# The part of seed 004 and Marlin's thermistor type 11: 100 kOhm at 25 C, beta 3950.
B3950 = SteinhartHart.from_beta(100000.0, 3950.0)
PULLUP_OHM = 4700.0  # Marlin's default pull-up (createTemperatureLookupMarlin.py --rp)


@dataclass(frozen=True)
class Divider:
    """Thermistor on the low side of a pull-up divider into a 10-bit ADC (ratio-metric)."""

    part: SteinhartHart = B3950
    pullup_ohm: float = PULLUP_OHM

    def adc_exact(self, temp_c: float) -> float:
        """Unquantised 10-bit ADC reading, ``1024 * R / (R + Rp)`` (Marlin's table convention)."""
        r = self.part.resistance_ohm(temp_c)
        return ADC_COUNTS * r / (r + self.pullup_ohm)

    def temp_at_adc(self, adc: float) -> float:
        """Inverse of ``adc_exact``: temperature for a (fractional) 10-bit reading in (0, 1024)."""
        return self.part.temp_c(self.pullup_ohm * adc / (ADC_COUNTS - adc))

    def temp_at_raw(self, raw: float) -> float:
        """Temperature for an oversampled raw value (sum of OVERSAMPLENR samples)."""
        return self.temp_at_adc(raw / OVERSAMPLENR)


def _table_rows(divider: Divider, tolerance_c, hot_raw: int, cold_raw: int) -> list[int]:
    """Greedy breakpoints on the raw axis so linear interpolation stays within tolerance.

    ``tolerance_c(temp_c)`` gives the allowed interpolation error at a temperature. Every raw
    value between two chosen rows is checked against the exact curve.
    """
    raws = np.arange(hot_raw, cold_raw + 1)
    temps = np.array([divider.temp_at_raw(float(r)) for r in raws])
    tols = np.array([tolerance_c(t) for t in temps])
    rows = [0]
    start = 0
    while start < len(raws) - 1:
        end = start + 1
        # Extend the segment as far as every interior point stays within tolerance.
        while end + 1 < len(raws):
            cand = end + 1
            seg = slice(start, cand + 1)
            line = temps[start] + (temps[cand] - temps[start]) * (raws[seg] - raws[start]) / (
                raws[cand] - raws[start]
            )
            if np.any(np.abs(line - temps[seg]) > tols[seg]):
                break
            end = cand
        rows.append(end)
        start = end
    return [int(raws[i]) for i in rows]


def default_tolerance_c(temp_c: float) -> float:
    """Interpolation error allowed when building a table: tight where printers work."""
    return 0.05 if -10.0 <= temp_c <= 320.0 else 1.0


# Interpolation bound over 20..280 C: the 0.05 C breakpoint tolerance, plus 1/64 C for storing each
# row's temperature in Q10.5, plus 1/64 C for the rounded integer division (see docs/firmware.md).
TABLE_ERROR_BOUND_C = 0.05 + 1.0 / 64 + 1.0 / 64


@dataclass(frozen=True)
class TempTable:
    """A firmware lookup table: ``raw`` ascending (int16), ``temp_q5`` descending (int16, Q10.5).

    Like Marlin's tables it lives in flash (4 bytes a row) and is searched by bisection; raw
    values outside the table read as the first (hottest) or last (coldest) row.
    """

    raw: tuple[int, ...]
    temp_q5: tuple[int, ...]

    def __post_init__(self) -> None:
        if len(self.raw) != len(self.temp_q5) or len(self.raw) < 2:
            raise ValueError("a table needs at least two rows of (raw, temp)")
        for v in (*self.raw, *self.temp_q5):
            if not INT16_MIN <= v <= INT16_MAX:
                raise ValueError(f"table value {v} does not fit int16")

    @classmethod
    def generate(
        cls,
        divider: Divider = Divider(),
        tolerance_c=default_tolerance_c,
        hot_adc: int = 1,
        cold_adc: int = 1021,
    ) -> TempTable:
        """Build a table for a divider, from ``OV(hot_adc)`` to ``OV(cold_adc)`` like type 11."""
        rows = _table_rows(divider, tolerance_c, hot_adc * OVERSAMPLENR, cold_adc * OVERSAMPLENR)
        return cls(tuple(rows), tuple(c_to_q5(divider.temp_at_raw(r)) for r in rows))

    @property
    def flash_bytes(self) -> int:
        """Flash the table takes on the MCU: int16 raw + int16 temperature per row."""
        return 4 * len(self.raw)

    def lookup_q5(self, raw: int) -> int:
        """Raw ADC sum -> celsius_q5, integer bisection and rounded integer interpolation.

        The search mirrors Marlin's ``SCAN_THERMISTOR_TABLE``; ``(raw - v0) * (t1 - t0)`` is at
        most 16368 * 65535 < 2**31, so the product fits the int32 the MCU computes it in.
        """
        raws, temps = self.raw, self.temp_q5
        lo, hi = 0, len(raws)
        while True:
            mid = (lo + hi) >> 1
            if mid == 0:
                return temps[0]
            if mid == lo or mid == hi:
                return temps[-1]
            v0, v1 = raws[mid - 1], raws[mid]
            if raw < v0:
                hi = mid
            elif raw > v1:
                lo = mid
            else:
                t0, t1 = temps[mid - 1], temps[mid]
                return t0 + div_round((raw - v0) * (t1 - t0), v1 - v0)

    def lookup_f32(self, raw: int) -> np.float32:
        """The same search with Marlin's float32 interpolation (the reference for the integer one)."""
        raws, temps = self.raw, self.temp_q5
        f32 = np.float32
        if raw <= raws[0]:
            return f32(temps[0]) / f32(TEMP_ONE)
        if raw >= raws[-1]:
            return f32(temps[-1]) / f32(TEMP_ONE)
        lo, hi = 0, len(raws) - 1
        while hi - lo > 1:
            mid = (lo + hi) >> 1
            if raws[mid] <= raw:
                lo = mid
            else:
                hi = mid
        t0 = f32(temps[lo]) / f32(TEMP_ONE)
        t1 = f32(temps[hi]) / f32(TEMP_ONE)
        frac = f32(raw - raws[lo]) * (t1 - t0) / f32(raws[hi] - raws[lo])
        return t0 + frac

    def count_c(self, temp_c: float, divider: Divider = Divider()) -> float:
        """One ADC count near ``temp_c``, in degC: what a noiseless reading (16 equal samples) steps by."""
        raw = OVERSAMPLENR * int(divider.adc_exact(temp_c))
        return (self.lookup_q5(raw) - self.lookup_q5(raw + OVERSAMPLENR)) / TEMP_ONE

    def raw_threshold(self, temp_c: int, *, above: bool) -> int:
        """Marlin's MINTEMP/MAXTEMP raw threshold, found at init by stepping raw by OVERSAMPLENR.

        For an NTC (raw falls as it heats): ``above=False`` starts at the coldest raw and steps
        down until the reading is no longer below ``temp_c`` (raw_min); ``above=True`` starts at
        the hottest raw and steps up until the reading is no longer above ``temp_c`` (raw_max).
        """
        limit_q5 = temp_c * TEMP_ONE
        if above:
            raw = 0
            while self.lookup_q5(raw) > limit_q5:
                raw += OVERSAMPLENR
        else:
            raw = MAX_RAW_THERMISTOR_VALUE
            while self.lookup_q5(raw) < limit_q5:
                raw -= OVERSAMPLENR
        return raw


# Type 11's table (B3950, 4.7 kOhm pull-up), stored as Marlin stores thermistor_11.h: the rows
# ``TempTable.generate()`` builds (tests/firmware_port/test_thermistor.py checks that it still builds these),
# kept as constants because building them costs 0.15 to 0.45 s of CPU at every command's start.
_B3950_RAW = (
    16, 18, 20, 22, 25, 28, 32, 37, 43, 50, 59, 70, 84, 101, 123, 151, 187, 234, 296, 378, 467, 495, 525, 557,
    591, 628, 667, 709, 754, 803, 856, 913, 974, 1040, 1111, 1188, 1271, 1361, 1458, 1563, 1677, 1800, 1934,
    2079, 2237, 2409, 2596, 2800, 3022, 3265, 3531, 3822, 4142, 4494, 4883, 5314, 5796, 6339, 6961, 7695, 8631,
    11041, 11860, 12495, 13019, 13464, 13846, 14177, 14464, 14714, 14933, 15124, 15291, 15437, 15564, 15675,
    15772, 15856, 15929, 15992, 16047, 16095, 16136, 16172, 16203, 16229, 16252, 16321, 16336,
)
_B3950_TEMP_Q5 = (
    30029, 28676, 27543, 26576, 25356, 24343, 23224, 22089, 20997, 19975, 18931, 17929, 16936, 16005, 15079,
    14186, 13321, 12480, 11662, 10872, 10233, 10063, 9895, 9728, 9564, 9398, 9237, 9075, 8915, 8753, 8592, 8431,
    8273, 8114, 7957, 7799, 7643, 7486, 7331, 7176, 7021, 6867, 6712, 6558, 6403, 6248, 6093, 5937, 5781, 5623,
    5463, 5302, 5139, 4972, 4801, 4625, 4442, 4249, 4042, 3812, 3533, 2838, 2591, 2388, 2209, 2045, 1892, 1748,
    1611, 1480, 1353, 1231, 1112, 996, 883, 772, 664, 558, 454, 353, 253, 154, 58, -39, -134, -224, -316, -714,
    -851,
)
B3950_TABLE = TempTable(_B3950_RAW, _B3950_TEMP_Q5)
