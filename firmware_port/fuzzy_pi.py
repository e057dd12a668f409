"""The fuzzy-like PI controller of seed 004 (El-Fakharany, Atia, Abu El-Sebah 2018).

A Mamdani controller on the error ``e = target - T`` and its change ``ce = e[k] - e[k-1]``:
n sets on each input (odd, default 9), both normalised 0..100 over a configured range (eq. 1),
isosceles triangles of half-width ``br = 100/(n+1)`` centred at ``(k+1)*br`` (eqs. 2-7), the
outermost two sets trapezoids (full membership beyond their centre); rule ``(i, j)`` fires output
set ``i + j`` of ``2n-1`` (eq. 8, Table 1), shaped by the same eqs. 2-7 on their own 0..100 axis;
min-max inference; centroid defuzzification. The crisp
output is a *change* of PWM duty, accumulated into the duty and clamped to ``[0, out_max]``:
a velocity-form PI whose gains are set by the three ranges and whose clamp is its anti-windup.

``FuzzyPi`` is the integer port (what the ATmega328 runs); ``FuzzyPiFloat`` is the same law in
Python float (float64), literally from the paper's equations, as the oracle. Float64 rather than
float32 because the oracle is for the *law*: float32 would add an accumulator rounding of the same
order as the integer port's and blur the bound the tests check.

Integer formats (why: one set step must be an exact power of two for any n, so the paper's
``a, b, c`` breakpoint tables become shifts and memberships of neighbours sum to exactly 1):
- normalised position: int32, in units of br/4096, so the paper's 0..100 is 0..(n+1)*4096 and
  set k is centred at (k+1)*4096; 0.015 degC a unit on the hotend preset, finer than celsius_q5;
- membership degree: uint16, Q12 (4096 = 1.0);
- output axis: sampled on an integer grid of 8 points per output set step, 0..2n*8 (the zero
  output set n-1 at n*8); the centroid is the sampled centroid of the max of the clipped output
  sets (the paper's "centroid", evaluated on a grid), held as int32 Q9 grid units;
- duty: int32, Q16.16 counts of 0..255, so a change of a few thousandths of a count per sample
  (the bed's integral action near the setpoint) is not rounded away.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from firmware_port.fixed import INT16_MAX, clamp, div_round, shr_round, to_q, wrap_s32
from firmware_port.lane_law import LaneLaw, record_dtype, register
from firmware_port.params import Param, ParamSpace
from firmware_port.thermistor import TEMP_FRAC_BITS, TEMP_ONE

N_SETS_MIN = 3
N_SETS_MAX = 31  # (n+1)/2 * 4096 * max |e| (32767) must fit the int32 product in _normalise
BR_BITS = 12  # input axis: one set step br = 4096 units; membership degrees Q12
MU_ONE = 1 << BR_BITS
GRID_BITS = 3  # output axis: 8 samples per output set step
CENTROID_BITS = 9  # centroid offset in Q9 grid units
DU_FRAC_BITS = 4  # output-change range stored in Q4 counts
DUTY_BITS = 16  # duty accumulator Q16.16 counts
RANGE_Q5_MAX = INT16_MAX  # error and change-of-error ranges are int16 celsius_q5
DU_MAX_COUNTS = 255
OUT_MAX_COUNTS = 255  # Marlin's PID_MAX: the 0..255 power scale


@dataclass(frozen=True)
class FuzzyPiConfig:
    """The user's settings: the number of sets and the three symmetric ranges of seed 004.

    Ranges are symmetric about zero. ``err_range_c`` and ``derr_range_c`` must be multiples of
    1/32 degC (celsius_q5) and ``du_range_counts`` a multiple of 1/16 count, so that the integer
    port holds them exactly and the float reference runs the very same law.
    """

    err_range_c: float  # error normalised over -range..+range (eq. 1), saturated beyond, degC
    derr_range_c: float  # the same for the change of error, degC per control sample
    du_range_counts: float  # change of duty at the ends of the output axis, counts per sample
    n_sets: int = 9  # sets per input; the output has 2n - 1
    out_max: int = OUT_MAX_COUNTS  # duty ceiling, counts of 0..255

    def __post_init__(self) -> None:
        if not (isinstance(self.n_sets, int) and self.n_sets % 2 == 1
                and N_SETS_MIN <= self.n_sets <= N_SETS_MAX):
            raise ValueError(f"n_sets must be odd in {N_SETS_MIN}..{N_SETS_MAX}, got {self.n_sets!r}")
        _check_q("err_range_c", self.err_range_c, TEMP_FRAC_BITS, RANGE_Q5_MAX)
        _check_q("derr_range_c", self.derr_range_c, TEMP_FRAC_BITS, RANGE_Q5_MAX)
        _check_q("du_range_counts", self.du_range_counts, DU_FRAC_BITS, DU_MAX_COUNTS << DU_FRAC_BITS)
        if not (isinstance(self.out_max, int) and 0 <= self.out_max <= OUT_MAX_COUNTS):
            raise ValueError(f"out_max must be an integer in 0..{OUT_MAX_COUNTS}, got {self.out_max!r}")

    @classmethod
    def from_input_range(cls, input_min_c: float, input_max_c: float, **settings: Any) -> FuzzyPiConfig:
        """The paper's "input min/max" read literally: ``err_range_c = input_max - input_min``.

        Every error of a reading inside the input range from a setpoint inside it lies in
        +-(max - min), so eq. (1) never saturates. The sets are then 60 degC apart on the hotend
        (24 degC on the bed): coarse, but the integer axis still resolves 0.015 degC (0.006 degC),
        finer than the sensor's 1/32 degC, so the coarseness costs no resolution; near the setpoint
        the controller behaves like a PI whose integral time is ``err_range / derr_range`` samples.
        """
        return cls(err_range_c=input_max_c - input_min_c, **settings)


def _check_q(name: str, value: float, frac_bits: int, max_q: int) -> None:
    """Raise ValueError naming ``name`` unless ``value`` is an exact Q(frac_bits) in (0, max_q]."""
    scaled = value * (1 << frac_bits) if isinstance(value, (int, float)) else math.nan
    if not (math.isfinite(scaled) and scaled == int(scaled) and 0 < scaled <= max_q):
        raise ValueError(
            f"{name} must be a positive multiple of 1/{1 << frac_bits} up to "
            f"{max_q / (1 << frac_bits)}, got {value!r}"
        )


# Seed 004 gives no change-of-error or output-change range. Near the setpoint the law is a
# velocity-form PI with Kp ~ 0.56 * du_range / derr_range and an integral time of
# err_range / derr_range samples (n = 9: (n+1)/2n = 0.56); the ranges below were chosen on
# first-order plants with 0..20 s of sensor lag (the closed-loop test runs the hotend one).
# Hotend, section 4.2: n = 9 (17 output sets), input 0..300 degC, output 0..255, setpoint 214 degC.
# 40 W, 17 J/K (2.35 degC/s at full power): Kp ~ 12 counts/degC, Ti = 100 samples (16 s);
# derr_range 3 degC/sample (18 degC/s) leaves the full-power heating rate unsaturated.
SEED004_HOTEND = FuzzyPiConfig.from_input_range(0.0, 300.0, derr_range_c=3.0, du_range_counts=64.0)
SEED004_HOTEND_SETPOINT_C = 214
# Bed, section 4.1: n = 9, input 0..120 degC, output 0..220/255 (19 V on a 24 V supply),
# setpoint 105 degC. MK3 aluminium, ~400 J/K, 90 W (0.23 degC/s at full power):
# Kp ~ 36 counts/degC, Ti = 480 samples (79 s), overshoot under 0.5 degC in simulation.
SEED004_BED = FuzzyPiConfig.from_input_range(0.0, 120.0, derr_range_c=0.25, du_range_counts=16.0, out_max=220)
SEED004_BED_SETPOINT_C = 105

# Tuning bounds of the three ranges (log scale; each a power of two from its quantum): errors of
# 1 to 1023 degC, changes of 1/32 to 64 degC per sample, duty changes of 1/16 to 255 counts per sample.
ERR_RANGE_BOUNDS_C = (1.0, RANGE_Q5_MAX / (1 << TEMP_FRAC_BITS))
DERR_RANGE_BOUNDS_C = (1.0 / (1 << TEMP_FRAC_BITS), 64.0)
DU_RANGE_BOUNDS_COUNTS = (1.0 / (1 << DU_FRAC_BITS), float(DU_MAX_COUNTS))


def _held(value: float, frac_bits: int) -> float:
    """The nearest positive multiple of 2**-frac_bits: what the integer port can hold."""
    return max(round(value * (1 << frac_bits)), 1) / (1 << frac_bits)


def fuzzy_pi_space(default: FuzzyPiConfig = SEED004_HOTEND, integer: bool = True) -> ParamSpace:
    """Seed 004's controller as a tunable family: its three ranges (the scaling factors), searched on
    log scales; ``n_sets`` and ``out_max`` stay as in ``default``. Values are held as the integer port
    holds them (the nearest multiple of its quantum), so the integer and float builds run the same law."""

    def held(err_range_c: float, derr_range_c: float, du_range_counts: float) -> tuple[float, float, float]:
        return (_held(err_range_c, TEMP_FRAC_BITS), _held(derr_range_c, TEMP_FRAC_BITS),
                _held(du_range_counts, DU_FRAC_BITS))

    def factory(err_range_c: float, derr_range_c: float, du_range_counts: float) -> FuzzyPi | FuzzyPiFloat:
        config = replace(default, err_range_c=err_range_c, derr_range_c=derr_range_c, du_range_counts=du_range_counts)
        return FuzzyPi(config) if integer else FuzzyPiFloat(config)

    params = (Param("err_range_c", "C", *ERR_RANGE_BOUNDS_C, default.err_range_c, log=True),
              Param("derr_range_c", "C/sample", *DERR_RANGE_BOUNDS_C, default.derr_range_c, log=True),
              Param("du_range_counts", "counts/sample", *DU_RANGE_BOUNDS_COUNTS, default.du_range_counts, log=True))
    return ParamSpace("fuzzy_pi" if integer else "fuzzy_pi_float", params, factory, held=held)


def membership(pos: int, set_index: int, n_sets: int, br: int) -> int:
    """Degree of set ``set_index`` at ``pos`` on an axis 0..(n_sets+1)*br, in units of 1/br.

    Eqs. (3)-(7): centre ``b = (k+1)*br``, feet ``b -+ br``; sets 0 and n-1 are trapezoids.
    Serves both axes: the inputs (br = 4096, degree Q12) and the output grid (br = 8, Q3).
    """
    centre = (set_index + 1) * br
    if (set_index == 0 and pos <= centre) or (set_index == n_sets - 1 and pos >= centre):
        return br
    return max(0, br - abs(pos - centre))


def _fuzzify(pos: int, n_sets: int) -> list[tuple[int, int]]:
    """The (set, Q12 degree) pairs with a non-zero degree at ``pos``: one set or two neighbours."""
    left = min((pos >> BR_BITS) - 1, n_sets - 1)  # the set centred at or left of pos, or -1
    sets = []
    for k in (left, left + 1):
        if 0 <= k < n_sets:
            mu_q12 = membership(pos, k, n_sets, MU_ONE)  # uint16, Q12
            if mu_q12 > 0:
                sets.append((k, mu_q12))
    return sets


class FuzzyPi:
    """Integer fuzzy-like PI: what the ATmega328 runs, only ints and fixed.py helpers per sample.

    Intermediates of one update (n <= 31): position int32 <= 131072; degrees uint16 Q12;
    centroid sums int32 (den <= 33*4096, |num| <= 16*den); centroid int32 Q9 grid units
    |off| <= 31*8*512; off * du_range_q4 < 2**29; duty + change < 2**26.
    """

    check_interval_ms = None

    def __init__(self, config: FuzzyPiConfig = SEED004_HOTEND) -> None:
        # Configuration (a C const struct, or RAM if settable by G-code like Marlin's gains).
        self.n_sets = config.n_sets  # uint8
        self.err_range_q5 = to_q(config.err_range_c, TEMP_FRAC_BITS)  # int16, celsius_q5
        self.derr_range_q5 = to_q(config.derr_range_c, TEMP_FRAC_BITS)  # int16, celsius_q5 per sample
        self.du_range_q4 = to_q(config.du_range_counts, DU_FRAC_BITS)  # int16, Q4 counts
        self.out_max = config.out_max  # uint8, counts of 0..255
        # State.
        self.duty_q16 = 0  # int32, Q16.16 counts of 0..out_max
        self.err_prev_q5 = 0  # int32, celsius_q5: the error of the previous sample
        self.have_prev = 0  # uint8, bool: err_prev_q5 holds a sample since the last reset

    def __repr__(self) -> str:
        return f"FuzzyPi(sets={self.n_sets}, err_range_c={self.err_range_q5 / TEMP_ONE:g}, " \
               f"derr_range_c={self.derr_range_q5 / TEMP_ONE:g}, du_range_counts={self.du_range_q4 / (1 << DU_FRAC_BITS):g}, " \
               f"out_max={self.out_max}, duty={self.duty_q16 / (1 << 16):.2f})"

    def reset(self) -> None:
        """Forget the duty and the previous error (as Marlin's pid_reset clears the integral)."""
        self.duty_q16 = 0
        self.have_prev = 0

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        """One control step: the duty (0..out_max counts) after adding this sample's change.

        Target 0 switches the heater off and resets, as Marlin's PID does; the first sample
        after a reset has no change of error.
        """
        if target_c == 0:
            self.reset()
            return 0
        err_q5 = (target_c << TEMP_FRAC_BITS) - temp_q5  # int32, |err| < 2**17
        derr_q5 = err_q5 - self.err_prev_q5 if self.have_prev else 0  # int32, |derr| < 2**18
        self.err_prev_q5, self.have_prev = err_q5, 1
        change_q16 = self.change_q16(err_q5, derr_q5)
        self.duty_q16 = clamp(self.duty_q16 + change_q16, 0, self.out_max << DUTY_BITS)
        return shr_round(self.duty_q16, DUTY_BITS)

    def change_q16(self, err_q5: int, derr_q5: int) -> int:
        """The fuzzy law: change of duty (int32, Q16.16 counts) for an error and its change."""
        n = self.n_sets
        err_sets = _fuzzify(normalise(err_q5, self.err_range_q5, n), n)
        derr_sets = _fuzzify(normalise(derr_q5, self.derr_range_q5, n), n)
        # Min-max inference. Two neighbours per input fire at most three output sets, k_lo..k_hi.
        k_lo = err_sets[0][0] + derr_sets[0][0]
        k_hi = err_sets[-1][0] + derr_sets[-1][0]
        strength_q12 = [0] * (k_hi - k_lo + 1)  # uint16[<= 3], Q12
        for i, mu_err in err_sets:
            for j, mu_derr in derr_sets:
                strength_q12[i + j - k_lo] = max(strength_q12[i + j - k_lo], min(mu_err, mu_derr))
        # Sampled centroid over the support of the fired sets, positions from its midpoint (an
        # integer: G is even); summing about the midpoint keeps num small and the law exactly odd.
        grid = 1 << GRID_BITS
        y_mid = (k_lo + k_hi + 2) << (GRID_BITS - 1)  # uint16, grid units
        num = 0  # int32, sum of (y - y_mid) * degree
        den = 0  # int32, sum of degree (>= 6 * 4096: some rule fires at >= 1/2)
        for y in range(k_lo << GRID_BITS, ((k_hi + 2) << GRID_BITS) + 1):
            mu_q12 = 0  # uint16, Q12: the aggregated (max of clipped) output degree at y
            for k in range(k_lo, k_hi + 1):
                clipped = min(strength_q12[k - k_lo],
                              membership(y, k, 2 * n - 1, grid) << (BR_BITS - GRID_BITS))
                mu_q12 = max(mu_q12, clipped)
            num += (y - y_mid) * mu_q12
            den += mu_q12
        offset_q9 = ((y_mid - n * grid) << CENTROID_BITS) + div_round(
            wrap_s32(num << CENTROID_BITS), den
        )  # int32, Q9 grid units from the zero output set's centre
        # change = offset / (n * grid) * du_range; Q9 * Q4 / (n * 8) is Q16 since 9+4+3 = 16.
        return div_round(wrap_s32(offset_q9 * self.du_range_q4), n)



def normalise(value_q5: int, range_q5: int, n_sets: int) -> int:
    """Eq. (1) on the integer axis, value saturated to +-range: 0..(n+1)*4096, zero at the middle."""
    half = (n_sets + 1) << (BR_BITS - 1)  # int32, the axis midpoint (the zero set's centre)
    value_q5 = clamp(value_q5, -range_q5, range_q5)  # int16
    return half + div_round(wrap_s32(value_q5 * half), range_q5)


# -- the compiled batch's lane law (firmware_port/lane_law.py) --------------------------------------
def _fuzzify_lane(pos: int, n: int) -> tuple[int, int, int, int]:
    """``_fuzzify`` as (first set, its degree, second set, its degree): the second the first, degree 0,
    when only one fires."""
    one = 1 << BR_BITS
    left = min((pos >> BR_BITS) - 1, n - 1)
    k0, mu0, k1, mu1 = -1, 0, -1, 0
    for k in (left, left + 1):
        if 0 <= k < n:
            mu = membership(pos, k, n, one)
            if mu > 0:
                if k0 < 0:
                    k0, mu0 = k, mu
                else:
                    k1, mu1 = k, mu
    if k1 < 0:
        k1 = k0
    return k0, mu0, k1, mu1


def _change_lane(p, err_q5: int, derr_q5: int) -> int:
    """``FuzzyPi.change_q16``: min-max inference over the (at most four) fired rules, sampled centroid."""
    n = p.n_sets
    ek0, emu0, ek1, emu1 = _fuzzify_lane(normalise(err_q5, p.err_range_q5, n), n)
    dk0, dmu0, dk1, dmu1 = _fuzzify_lane(normalise(derr_q5, p.derr_range_q5, n), n)
    k_lo, k_hi = ek0 + dk0, ek1 + dk1
    s0 = s1 = s2 = 0  # strengths of output sets k_lo, k_lo + 1, k_lo + 2
    for a in range(2):
        i, mu_e = (ek0, emu0) if a == 0 else (ek1, emu1)
        if a == 1 and (emu1 == 0 or ek1 == ek0):
            continue
        for b in range(2):
            j, mu_d = (dk0, dmu0) if b == 0 else (dk1, dmu1)
            if b == 1 and (dmu1 == 0 or dk1 == dk0):
                continue
            w, slot = min(mu_e, mu_d), i + j - k_lo
            if slot == 0:
                s0 = max(s0, w)
            elif slot == 1:
                s1 = max(s1, w)
            else:
                s2 = max(s2, w)
    grid = 1 << GRID_BITS
    y_mid = (k_lo + k_hi + 2) << (GRID_BITS - 1)
    num = den = 0
    for y in range(k_lo << GRID_BITS, ((k_hi + 2) << GRID_BITS) + 1):
        mu = 0
        for k in range(k_lo, k_hi + 1):
            strength = s0 if k == k_lo else s1 if k == k_lo + 1 else s2
            mu = max(mu, min(strength, membership(y, k, 2 * n - 1, grid) << (BR_BITS - GRID_BITS)))
        num += (y - y_mid) * mu
        den += mu
    offset_q9 = ((y_mid - n * grid) << CENTROID_BITS) + div_round(wrap_s32(num << CENTROID_BITS), den)
    return div_round(wrap_s32(offset_q9 * p.du_range_q4), n)


def fuzzy_pi_lane(p, s, temp_q5, target_c, board):
    """``FuzzyPi.update`` on one lane of the compiled batch: the duty after this sample's change."""
    if target_c == 0:
        s.duty_q16, s.have_prev = 0, 0
        return 0
    err_q5 = (target_c << TEMP_FRAC_BITS) - temp_q5
    derr_q5 = err_q5 - s.err_prev_q5 if s.have_prev else 0
    s.err_prev_q5, s.have_prev = err_q5, 1
    s.duty_q16 = clamp(s.duty_q16 + _change_lane(p, err_q5, derr_q5), 0, p.out_max << DUTY_BITS)
    return shr_round(s.duty_q16, DUTY_BITS)


# Every parameter is read from the first reading with a target: lanes share a heat-up only with their twins.
FUZZY_PI_LAW = register(LaneLaw(
    "fuzzy_pi", FuzzyPi, record_dtype(("n_sets", "err_range_q5", "derr_range_q5", "du_range_q4", "out_max")),
    record_dtype(("duty_q16", "err_prev_q5", "have_prev")), fuzzy_pi_lane), check=False)


class FuzzyPiFloat:
    """The same law in Python float, literally from the paper's equations: the oracle for FuzzyPi."""

    check_interval_ms = None

    def __init__(self, config: FuzzyPiConfig = SEED004_HOTEND) -> None:
        self.config = config
        self.duty = 0.0  # counts of 0..out_max
        self.err_prev_c = 0.0
        self.have_prev = False

    def __repr__(self) -> str:
        return f"FuzzyPiFloat({self.config!r}, duty={self.duty:.2f})"

    def reset(self) -> None:
        """Forget the duty and the previous error."""
        self.duty = 0.0
        self.have_prev = False

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        """One control step: the duty rounded to a count (halves up, as the integer port rounds)."""
        if target_c == 0:
            self.reset()
            return 0
        err_c = target_c - temp_q5 / TEMP_ONE
        derr_c = err_c - self.err_prev_c if self.have_prev else 0.0
        self.err_prev_c, self.have_prev = err_c, True
        self.duty = min(max(self.duty + self.change(err_c, derr_c), 0.0), float(self.config.out_max))
        return math.floor(self.duty + 0.5)

    def change(self, err_c: float, derr_c: float) -> float:
        """Change of duty in counts: min-max over the full rule table, sampled centroid."""
        cfg = self.config
        n = cfg.n_sets
        mu_err = [membership_pct(_normalised(err_c, cfg.err_range_c), k, n) for k in range(n)]
        mu_derr = [membership_pct(_normalised(derr_c, cfg.derr_range_c), k, n) for k in range(n)]
        strength = [0.0] * (2 * n - 1)
        for i in range(n):
            for j in range(n):
                strength[i + j] = max(strength[i + j], min(mu_err[i], mu_derr[j]))  # eq. (8)
        fired = [(k, s) for k, s in enumerate(strength) if s > 0.0]
        step = 100.0 / (2 * n) / (1 << GRID_BITS)  # the output grid, in normalised units
        num = den = 0.0
        for i in range(2 * n * (1 << GRID_BITS) + 1):
            y = i * step
            mu = max(min(s, membership_pct(y, k, 2 * n - 1)) for k, s in fired)
            num += y * mu
            den += mu
        return (num / den - 50.0) / 50.0 * cfg.du_range_counts


def _normalised(value: float, value_range: float) -> float:
    """Eq. (1) with min = -range, max = +range, the value saturated to the range."""
    value = min(max(value, -value_range), value_range)
    return (value + value_range) * 100.0 / (2.0 * value_range)


def membership_pct(val: float, k: int, n_sets: int) -> float:
    """Membership of set k of n on the 0..100 axis, eqs. (2)-(7), outer sets trapezoids."""
    br = 100.0 / (n_sets + 1)
    b = k * br + br
    a, c = b - br, b + br
    if (k == 0 and val <= b) or (k == n_sets - 1 and val >= b):
        return 1.0
    if a <= val <= b:
        return (val - a) / (b - a)
    if b < val <= c:
        return (c - val) / (c - b)
    return 0.0


# RAM and flash on the AVR, as C structs lay them out (no padding; uint8 1, int16 2, int32 4).
STATE_FIELDS = (("duty_q16", 4), ("err_prev_q5", 4), ("have_prev", 1))
CONFIG_FIELDS = (("n_sets", 1), ("err_range_q5", 2), ("derr_range_q5", 2), ("du_range_q4", 2), ("out_max", 1))


def ram_report(config: FuzzyPiConfig) -> dict[str, int]:
    """Bytes one heater's controller takes on the ATmega328.

    ============================  =====  ==============================================
    state (RAM)                       9  duty_q16 4, err_prev_q5 4, have_prev 1
    config (flash, or RAM)            8  n_sets 1, three ranges 2+2+2, out_max 1
    constant tables (flash)           0  breakpoints are shifts: br = 4096 units
    literal float a,b,c tables      420  for n = 9: 3 floats x (9 + 9 + 17) sets
    ============================  =====  ==============================================

    Seed 004 reports 0.3 KB of RAM for its whole sketch (Arduino's Serial alone holds two
    64-byte buffers). Two heaters here need 2 x 17 = 34 bytes. Literal float a, b, c tables
    (420 bytes for n = 9) would not fit in 0.3 KB, so the paper's sketch presumably computes them
    on the fly.
    """
    n = config.n_sets
    return {
        "state_bytes": sum(size for _, size in STATE_FIELDS),
        "config_bytes": sum(size for _, size in CONFIG_FIELDS),
        "table_bytes": 0,
        "float_abc_table_bytes": 3 * 4 * (n + n + 2 * n - 1),
    }
