"""Marlin's hotend/bed PID law in integer fixed point, as an ATmega328 would run it.

The law is Marlin 2.1's ``PID_t::get_pid_output`` (Marlin 2.1.x Marlin/src/module/temperature.h PID_t::get_pid_output()): bang-bang outside
+-PID_FUNCTIONAL_RANGE, a one-sided sum of errors clamped so ``Ki * i_sum <= PID_MAX``,
derivative on measurement through the ``PID_K1 = 0.95`` filter, output 0..255. Gains come in user
units (M301) and are scaled by ``PID_dT = 160/977 s`` as Marlin stores them.

Widths and scales (every intermediate is bounded in the comments; tests/firmware_port/marlin/test_pid_properties.py
checks the bounds over the whole documented domain):
- temperatures: celsius_q5, int16 Q10.5 (1/32 degC); targets int16 whole degC;
- error ``e_q5``: int32 Q.5 (in band |e| <= 320);
- terms and output: int32 Q.8 counts of the 0..255 output (1/256 count);
- products that can exceed 32 bits (integral and derivative) are formed in int64 (avr-gcc's
  ``long long``) and immediately shifted back into int32.
"""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction

import numpy as np

from firmware_port import fixed_lanes
from firmware_port.controller import PidGains
from firmware_port.fixed import checked_s32, checked_s64, clamp, div_round, shr_round
from firmware_port.lane_law import LaneLaw, field_names, record_dtype, register
from firmware_port.marlin.constants import (
    DEFAULT_BED_KD,
    DEFAULT_BED_KI,
    DEFAULT_BED_KP,
    DEFAULT_KD,
    DEFAULT_KI,
    DEFAULT_KP,
    PID_DT_S,
    PID_FUNCTIONAL_RANGE_C,
    PID_K1,
    PID_MAX,
)
from firmware_port.marlin.versions import MarlinVersion
from firmware_port.params import ParamSpace, pid_params
from firmware_port.thermistor import TEMP_FRAC_BITS

KP_FRAC_BITS = 12  # kp_q12: int32 Q.12, Kp in user units (Kp is not scaled by PID_dT)
KI_FRAC_BITS = 24  # ki_q24: int32 Q.24, Ki_int = Ki * PID_dT
KD_FRAC_BITS = 16  # kd_q16: int32 Q.16, Kd_int = Kd / PID_dT (< 2**15 for Kd <= KD_MAX)
OUT_FRAC_BITS = 8  # terms and output: Q.8 counts
P_SHIFT = KP_FRAC_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS  # Q.17 product -> Q.8
I_SHIFT = KI_FRAC_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS  # Q.29 product -> Q.8
D_SHIFT = KD_FRAC_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS  # Q.21 product -> Q.8

FUNCTIONAL_RANGE_Q5 = PID_FUNCTIONAL_RANGE_C << TEMP_FRAC_BITS  # 320
OUT_MAX_Q8 = PID_MAX << OUT_FRAC_BITS  # 65280
# Integral sum ceiling when Ki is tiny or zero: keeps i_sum in int32 (Ki*i_sum stays < PID_MAX).
I_SUM_CAP_Q5 = 1 << 30
I_MAX_FULL_SCALE = PID_MAX << (KI_FRAC_BITS + TEMP_FRAC_BITS)  # MAX_POW in Q.29 (Ki's Q.24 times Q.5)
# Derivative input saturation: |Kd_int * dT| <= 2**21 counts, far beyond any output, keeps the
# filter state and (raw - state) inside int32 in Q.8.
D_RAW_LIMIT_Q8 = 1 << (21 + OUT_FRAC_BITS)
D_FILTER_DIVISOR = int(1 / (1 - PID_K1))  # 1 - PID_K1 = 0.05 = 1/20 exactly


HOTEND_GAINS = PidGains(DEFAULT_KP, DEFAULT_KI, DEFAULT_KD)
BED_GAINS = PidGains(DEFAULT_BED_KP, DEFAULT_BED_KI, DEFAULT_BED_KD)

PREV_TEMP_EVERY_SAMPLE = MarlinVersion.V2_0  # Marlin 2.0.x: previous temperature updated on every call
PREV_TEMP_IN_BAND = MarlinVersion.V2_1  # Marlin 2.1.x: only in band, so re-entering the band kicks D


# The float product value * scale * 2**frac_bits is within 4e-16 of the exact one, relative (the
# decimal's, the factor's and the product's roundings): it decides unless it lies this near a half.
HALF_MARGIN = 1e-13  # relative: 250 times the float product's error bound
FLOAT_EXACT_BELOW = 2.0**52  # where a float still has a fractional part to look at


def float_decides(v):
    """Whether the float product v (a float or an array) rounds as the exact one does: finite, below
    2**52, and not within its rounding error of a half."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(v) & (np.abs(v) < FLOAT_EXACT_BELOW) & (np.abs(v - np.floor(v) - 0.5) > HALF_MARGIN * np.abs(v))


class QScale:
    """``round(value * scale * 2**frac_bits)`` from the value's decimal (half to even), exactly: in
    floats where ``float_decides``, else in fractions."""

    def __init__(self, scale: Fraction, frac_bits: int):
        self.exact = scale * (1 << frac_bits)
        self.factor = float(self.exact)

    def __repr__(self) -> str:
        return f"QScale(x {self.exact})"

    def __call__(self, value: float) -> int:
        x = float(value)
        v = x * self.factor
        return round(v) if float_decides(v) else round(Fraction(repr(x)) * self.exact)

    def many(self, values: np.ndarray) -> np.ndarray:
        """The same on an array, int64: each element as ``self(value)`` gives it."""
        x = np.asarray(values, dtype=float)
        with np.errstate(over="ignore"):
            v = x * self.factor
        sure = float_decides(v)
        out = np.zeros(x.shape, np.int64)
        out[sure] = np.rint(v[sure])  # no half among them: rint and round agree
        for i in np.flatnonzero(~sure):
            out[i] = self(x[i])
        return out


def q_scaled(value: float, scale: Fraction, frac_bits: int) -> int:
    """User gain -> internal Q integer: ``round(value * scale * 2**frac_bits)`` from its decimal."""
    return QScale(scale, frac_bits)(value)


KP_Q12, KI_Q24, KD_Q16 = QScale(Fraction(1), KP_FRAC_BITS), QScale(PID_DT_S, KI_FRAC_BITS), \
    QScale(1 / PID_DT_S, KD_FRAC_BITS)  # M301's gains into the law's integers


def i_max_q5(ki_q24: int) -> int:
    """Marlin's iState ceiling MAX_POW / Ki in Q.5 with Ki in Q.24: floor(255 * 2**29 / ki_q24). A negative Ki
    gives a negative ceiling, which constrain() returns for any sum >= 0, as on the AVR."""
    return clamp(I_MAX_FULL_SCALE // ki_q24, -I_SUM_CAP_Q5, I_SUM_CAP_Q5) if ki_q24 else I_SUM_CAP_Q5


class PidFixed:
    """Marlin's PID law in integer arithmetic. One instance per heater.

    State (as the C struct, 11 bytes):
        i_sum_q5:  int32, Q.5 degC*samples, 0..i_max_q5 (one-sided sum of errors)
        d_term_q8: int32, Q.8 counts, |d| <= 2**29 (filtered derivative term)
        prev_q5:   int16, Q10.5 degC (previous temperature for the derivative)
        reset:     uint8 flag (clear i and d on entering the band)
    Constants per gain set (16 bytes): kp_q12, ki_q24, kd_q16, i_max_q5 (int32 each).
    """

    check_interval_ms = None
    STATE_BYTES = 4 + 4 + 2 + 1
    GAIN_BYTES = 4 * 4

    def __init__(self, gains: PidGains = HOTEND_GAINS, prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE):
        if prev_temp_mode not in (PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND):
            raise ValueError(f"prev_temp_mode must be {PREV_TEMP_EVERY_SAMPLE!r} or {PREV_TEMP_IN_BAND!r}")
        self.prev_temp_mode = prev_temp_mode
        self.set_gains(gains)
        self.prev_q5 = 0  # Marlin starts temp_dState at 0.0
        self.reset()

    def __repr__(self) -> str:
        return f"PidFixed({self.gains!r}, prev_temp_mode={str(self.prev_temp_mode)!r})"

    def set_gains(self, gains: PidGains) -> None:
        """M301: scale user gains into Q integers (configuration time) and reset the loop."""
        self.gains = gains
        self.kp_q12 = KP_Q12(gains.kp)  # <= 2**22
        self.ki_q24 = KI_Q24(gains.ki)  # <= 2**28
        self.kd_q16 = KD_Q16(gains.kd)  # < 2**31
        self.i_max_q5 = i_max_q5(self.ki_q24)
        self.reset()

    def reset(self) -> None:
        """Forget the integral and derivative (Marlin's ``pid_reset``)."""
        self.i_sum_q5 = 0
        self.d_term_q8 = 0
        self.reset_pending = True
        self.p_q8 = self.i_q8 = 0  # the last update's P and I terms, Q.8 (published; the law never reads them)

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """One step on a fresh reading; returns the output 0..255 (soft PWM gets ``>> 1``)."""
        out_q8 = self.update_q8(temp_q5, target_c)
        return out_q8 >> OUT_FRAC_BITS

    def update_q8(self, temp_q5: int, target_c: int) -> int:
        """The law with its Q.8 output (0..65280), for comparison with the float reference."""
        e_q5 = checked_s32((target_c << TEMP_FRAC_BITS) - temp_q5)  # |e| < 2**16
        self.p_q8 = self.i_q8 = 0
        if target_c == 0 or e_q5 < -FUNCTIONAL_RANGE_Q5:
            out_q8 = 0
            self.reset_pending = True
        elif e_q5 > FUNCTIONAL_RANGE_Q5:
            out_q8 = OUT_MAX_Q8
            self.reset_pending = True
        else:
            if self.reset_pending:
                self.reset_pending = False
                self.i_sum_q5 = 0
                self.d_term_q8 = 0
            self.i_sum_q5 = clamp(checked_s32(self.i_sum_q5 + e_q5), 0, self.i_max_q5)
            # kp_q12 * e_q5 <= 2**22 * 320 < 2**31: int32 product, Q.17 -> Q.8.
            p_q8 = shr_round(checked_s32(self.kp_q12 * e_q5), P_SHIFT)
            # ki_q24 * i_sum_q5 <= 255 * 2**29 (int64), Q.29 -> Q.8 <= 65280.
            i_q8 = shr_round(checked_s64(self.ki_q24 * self.i_sum_q5), I_SHIFT)
            # kd_q16 * dT_q5 is int64 (< 2**31 * 2**16), Q.21 -> Q.8, saturated to +-2**29.
            d_prod = checked_s64(self.kd_q16 * checked_s32(self.prev_q5 - temp_q5))
            d_in_q8 = shr_round(d_prod, D_SHIFT)
            d_in_q8 = clamp(d_in_q8, -D_RAW_LIMIT_Q8, D_RAW_LIMIT_Q8)
            # d += (d_in - d) / 20: |d_in - d| <= 2**30 fits int32.
            self.d_term_q8 += div_round(checked_s32(d_in_q8 - self.d_term_q8), D_FILTER_DIVISOR)
            # p + i + d: |sum| < 2**27 + 2**16 + 2**29 < 2**31.
            out_q8 = clamp(checked_s32(p_q8 + i_q8 + self.d_term_q8), 0, OUT_MAX_Q8)
            self.p_q8, self.i_q8 = p_q8, i_q8
            if self.prev_temp_mode == PREV_TEMP_IN_BAND:
                self.prev_q5 = temp_q5
        if self.prev_temp_mode == PREV_TEMP_EVERY_SAMPLE:
            self.prev_q5 = temp_q5
        return out_q8


    def signals(self) -> dict[str, float]:
        """The last update's P and I terms (0 outside the band, where the output is bang-bang) and the
        filtered D term, in output counts of 0..255."""
        return {"p_counts": self.p_q8 / 256, "i_counts": self.i_q8 / 256, "d_counts": self.d_term_q8 / 256}


# -- lanes: the numpy batch's vectorised law, and the compiled batch's lane law ------------------------
class PidLanes:
    """``PidFixed.update_q8`` on N lanes; gains scaled by the scalar class itself; the prev-temperature
    mode one for all lanes or one per lane."""

    def __init__(self, gains: Sequence[PidGains | PidFixed], prev_temp_mode: str | Sequence[str] = PREV_TEMP_EVERY_SAMPLE):
        """One lane per gain set (in ``prev_temp_mode``), or per ``PidFixed`` (its gains and mode)."""
        modes = [prev_temp_mode] * len(gains) if isinstance(prev_temp_mode, str) else list(prev_temp_mode)
        if len(modes) != len(gains) or not set(modes) <= {PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND}:
            raise ValueError(f"prev_temp_mode: one of {PREV_TEMP_EVERY_SAMPLE!r}, {PREV_TEMP_IN_BAND!r} per lane")
        modes = [g.prev_temp_mode if isinstance(g, PidFixed) else mode for g, mode in zip(gains, modes)]
        self.every_sample = np.array([mode == PREV_TEMP_EVERY_SAMPLE for mode in modes], dtype=bool)
        # PidFixed's own scaling (QScale, i_max_q5), on arrays: the gains of the lanes given as PidGains
        user = np.array([(p.kp, p.ki, p.kd) for p in (g.gains if isinstance(g, PidFixed) else g for g in gains)],
                        dtype=float).reshape(-1, 3)
        self.kp_q12, self.ki_q24, self.kd_q16 = (q.many(user[:, i]) for i, q in enumerate((KP_Q12, KI_Q24, KD_Q16)))
        self.i_max_q5 = np.array([i_max_q5(int(ki)) for ki in self.ki_q24], dtype=np.int64)
        n = len(gains)
        self.i_sum_q5 = np.zeros(n, np.int64)
        self.d_term_q8 = np.zeros(n, np.int64)
        self.prev_q5 = np.zeros(n, np.int64)
        self.reset_pending = np.ones(n, bool)


    def __repr__(self) -> str:
        return f"PidLanes({len(self.every_sample)} lanes, {int(self.every_sample.sum())} updating T_prev every sample)"
    def update_q8(self, temp_q5: np.ndarray, target_c: int, active: np.ndarray) -> np.ndarray:
        """One step on the ``active`` lanes (others keep their state); Q.8 output, 0 elsewhere."""
        e = (target_c << TEMP_FRAC_BITS) - temp_q5
        off = active & ((target_c == 0) | (e < -FUNCTIONAL_RANGE_Q5))
        full = active & ~off & (e > FUNCTIONAL_RANGE_Q5)
        band = active & ~off & ~full
        fresh = band & self.reset_pending
        self.reset_pending = (self.reset_pending | off | full) & ~band
        i_sum = np.where(fresh, 0, self.i_sum_q5)
        d_term = np.where(fresh, 0, self.d_term_q8)
        i_sum = _constrain(i_sum + e, 0, self.i_max_q5)
        p = fixed_lanes.shr_round(self.kp_q12 * e, P_SHIFT)
        i = fixed_lanes.shr_round(self.ki_q24 * i_sum, I_SHIFT)
        d_in = np.clip(fixed_lanes.shr_round(self.kd_q16 * (self.prev_q5 - temp_q5), D_SHIFT), -D_RAW_LIMIT_Q8, D_RAW_LIMIT_Q8)
        d_term = d_term + fixed_lanes.div_round(d_in - d_term, D_FILTER_DIVISOR)
        self.i_sum_q5 = np.where(band, i_sum, self.i_sum_q5)
        self.d_term_q8 = np.where(band, d_term, self.d_term_q8)
        self.prev_q5 = np.where(np.where(self.every_sample, active, band), temp_q5, self.prev_q5)
        in_band = np.clip(p + i + d_term, 0, OUT_MAX_Q8)
        return np.where(full, OUT_MAX_Q8, np.where(band, in_band, 0))

    def output(self, temp_q5: np.ndarray, target_c: int, active: np.ndarray, now_ms: int) -> np.ndarray:
        """``PidFixed.update`` on the active lanes: 0..255 (0 elsewhere)."""
        return self.update_q8(temp_q5, target_c, active) >> OUT_FRAC_BITS


def _constrain(x: np.ndarray, lo: int, hi: np.ndarray) -> np.ndarray:
    """``fixed.clamp`` on lanes: a ceiling below the floor (a negative Ki's) wins only above the floor."""
    return np.where(x < lo, lo, np.where(x > hi, hi, x))


PID_PARAMS = record_dtype(("kp_q12", "ki_q24", "kd_q16", "i_max_q5", "every_sample"))  # PidFixed's, its mode
PID_STATE = record_dtype(("i_sum_q5", "d_term_q8", "prev_q5", "reset_pending"))  # PidFixed's state


def in_band(e_q5: int, target_c: int) -> bool:
    """Whether the error lies in the functional range, where the law reads its gains."""
    return -FUNCTIONAL_RANGE_Q5 <= e_q5 <= FUNCTIONAL_RANGE_Q5 and target_c != 0


def pid_lane(p, s, temp_q5, target_c, board):
    """``PidFixed.update`` on one lane of the compiled batch: 0..255 (``p``, ``s``: PID_PARAMS, PID_STATE)."""
    e_q5 = (target_c << TEMP_FRAC_BITS) - temp_q5
    if not in_band(e_q5, target_c):
        s.reset_pending = 1
        if p.every_sample:
            s.prev_q5 = temp_q5
        return PID_MAX if target_c != 0 and e_q5 > FUNCTIONAL_RANGE_Q5 else 0
    i_sum, d_term = (0, 0) if s.reset_pending else (s.i_sum_q5, s.d_term_q8)
    i_sum = clamp(i_sum + e_q5, 0, p.i_max_q5)
    p_q8 = shr_round(p.kp_q12 * e_q5, P_SHIFT)
    i_q8 = shr_round(p.ki_q24 * i_sum, I_SHIFT)
    d_in_q8 = clamp(shr_round(p.kd_q16 * (s.prev_q5 - temp_q5), D_SHIFT), -D_RAW_LIMIT_Q8, D_RAW_LIMIT_Q8)
    d_term = d_term + div_round(d_in_q8 - d_term, D_FILTER_DIVISOR)
    s.i_sum_q5, s.d_term_q8, s.prev_q5, s.reset_pending = i_sum, d_term, temp_q5, 0
    return clamp(p_q8 + i_q8 + d_term, 0, OUT_MAX_Q8) >> OUT_FRAC_BITS


def pid_tuned(p, s, temp_q5, target_c):
    """The law reads its gains in band only: outside, full power or off (the heat-up before the band)."""
    return in_band((target_c << TEMP_FRAC_BITS) - temp_q5, target_c)


def _records(lanes: PidLanes, dtype: np.dtype) -> np.ndarray:
    """The lanes' arrays named by the dtype's fields, as (N,) records."""
    out = np.zeros(len(lanes.kp_q12), dtype)
    for name in field_names(dtype):
        out[name] = getattr(lanes, name)
    return out


def _set_pid_state(lanes: PidLanes, state: np.ndarray) -> None:
    lanes.i_sum_q5, lanes.d_term_q8, lanes.prev_q5 = (state[name].copy() for name in ("i_sum_q5", "d_term_q8", "prev_q5"))
    lanes.reset_pending = state["reset_pending"].astype(bool)


PID_LAW = register(LaneLaw("pid", PidFixed, PID_PARAMS, PID_STATE, pid_lane, tuning=("kp_q12", "ki_q24", "kd_q16",
                                                                                     "i_max_q5"),
                           tuned=pid_tuned, lanes=PidLanes, pack=lambda lanes: _records(lanes, PID_PARAMS),
                           read=lambda lanes: _records(lanes, PID_STATE), write=_set_pid_state), check=False)


def pid_space(default: PidGains = HOTEND_GAINS, prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE) -> ParamSpace:
    """Marlin's fixed-point PID as a tunable family: Kp, Ki, Kd in M301 units."""
    return ParamSpace("pid", pid_params(default),
                      lambda kp, ki, kd: PidFixed(PidGains(kp, ki, kd), prev_temp_mode), pid=True,
                      autotune="M303")


def float_error_bound_counts(gains: PidGains, max_dtemp_c: float) -> float:
    """Worst-case |PidFixed - PidFloat| on the 0..255 output before truncation.

    Derived term by term (docs/firmware.md) for equal temperature inputs, while the derivative
    input is not saturated; ``max_dtemp_c`` is the largest |T_prev - T| the sequence feeds the
    derivative (a few degrees normally, large after an excursion in 2.1.x mode).
    """
    lsb = 2.0**-OUT_FRAC_BITS / 2  # half a Q.8 step: one rounding
    f32 = 2.0**-24  # float32 relative rounding
    gains = PidGains(abs(gains.kp), abs(gains.ki), abs(gains.kd))  # the terms' magnitudes bound their errors
    ki_int = gains.ki * float(PID_DT_S)
    kd_int = gains.kd / float(PID_DT_S)
    # P: Kp quantised to Q.12 over |e| <= 10, one rounding; float32 rounds Kp and the product.
    bound_p = PID_FUNCTIONAL_RANGE_C * (2.0**-KP_FRAC_BITS / 2 + 2 * f32 * gains.kp) + lsb
    # I: relative error of Ki (Q.24 vs float32) at full scale, the clamp level floored to the
    # Q.5 grid (worth Ki_int/32 counts), one rounding, float32 rounding of the product.
    bound_i = 0.0
    if ki_int > 0:
        rel_ki = (2.0**-KI_FRAC_BITS / 2) / ki_int + 3 * f32
        bound_i = PID_MAX * (rel_ki + f32) + ki_int / (1 << TEMP_FRAC_BITS) + lsb
    # D: Kd quantised to Q.16 and float32 rounding of the raw input pass through the unity-gain
    # filter; each step's rounding (fixed: one Q.8 rounding; float32: three roundings of a
    # value bounded by the input) accumulates at most 1/(1 - K1) = 20 times.
    raw_d_max = kd_int * max_dtemp_c
    bound_d = max_dtemp_c * 2.0**-KD_FRAC_BITS / 2 + 2 * f32 * raw_d_max + lsb
    bound_d += D_FILTER_DIVISOR * (lsb + 4 * f32 * raw_d_max)
    # The final sum: one float32 rounding per addition.
    return bound_p + bound_i + bound_d + 3 * f32 * 2 * (PID_MAX + raw_d_max)
