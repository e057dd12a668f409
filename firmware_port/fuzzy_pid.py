"""The fuzzy-PID of seed 001 (Fuzzy-PID nozzle temperature control, Southwest University 2022).

Section 3 of the paper: the error ``e = target - T`` and its rate ``ec = de/dt`` are quantised
by factors Ke = 0.4 /degC and Kec = 0.6 s/degC onto the universe [-3, 3] (saturated beyond) and
fuzzified by 7 uniform triangles NB..PB centred on -3..3; a two-input Mamdani system with the
three 7x7 rule tables of Fig. 7 (min for AND, max to aggregate) gives kp, ki and kd on the
output universe [0, 3] (7 triangles NB..PB centred 0, 0.5, ..., 3); centroid defuzzification;
output scaling factors 1. The PID then acts with those gains.

The paper is ambiguous about what the tables mean, so both readings are available:
- ``LITERAL``: the tables give the gains. Each gain is ``base * c`` with ``c`` the centroid in
  [0, 3]; the base gains are the paper's output scaling factors (1, 1, 1 in its loop).
- ``INCREMENTAL``: the tables give corrections to base gains (the usual meaning of a table with
  NB..PB outputs, e.g. on Ziegler-Nichols gains): ``base * (1 + span * (c - 1.5) / 1.5)``, so
  ZO keeps the base gain and NB/PB move it by -/+ ``span`` of itself.

The PID law (both versions): ``u = kp e + I + kd ec`` with ``I += ki e dt``. The integral
accumulates ``ki e`` rather than multiplying the stored sum of errors by the current ki, so a gain
change never jumps the output (a firmware needs this; Simulink's ``ki * integral(e)`` differs
only while ki moves). With an output range, I is clamped to it (anti-windup) and u saturates.

``FuzzyPid`` is the integer port for the ATmega328 board (same interface as ``PidFixed`` and
``FuzzyPi``); ``FuzzyPidFloat`` is the same law in float64: with exact constants for the paper's
continuous loop, or (``FuzzyPidFloat.board``) with the integer port's rounded constants as its
oracle on the board.

Integer formats:
- universe positions: int16 Q8 (256 = 1 unit), -768..768; membership degrees uint16 Q8;
- output universe: an integer grid of 16 points a unit (8 per set step), 0..48; the centroid is
  the sampled centroid of the max of the clipped output sets, as int32 Q12 units of [0, 3]
  (MATLAB's Fuzzy toolbox also samples, on 101 points);
- gain factors: int32 Q12; gains as ``PidFixed`` stores them (kp Q12, ki*dt Q24, kd/dt Q16);
- P, I, D terms and output: int32 Q8 counts of 0..255; products in int64 (avr-gcc long long).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX
from firmware_port.fixed import checked_s32, checked_s64, clamp, div_round, sat_s16, sat_s32, shr_round
from firmware_port.lane_law import LaneLaw, attributes, field_names, record_dtype, register, set_attributes
from firmware_port.marlin.constants import PID_DT_S, PID_MAX
from firmware_port.marlin.pid import (
    HOTEND_GAINS,
    KD_FRAC_BITS,
    KD_Q16,
    KI_FRAC_BITS,
    KI_Q24,
    KP_FRAC_BITS,
    KP_Q12,
    PidGains,
    q_scaled,
)
from firmware_port.params import Param, ParamSpace
from firmware_port.thermistor import TEMP_FRAC_BITS, TEMP_ONE

LITERAL, INCREMENTAL = "literal", "incremental"
READINGS = (LITERAL, INCREMENTAL)
LABELS = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")  # set index 0..6
N_SETS = len(LABELS)
HALF = N_SETS // 2  # the ZO set's index; the input universe is [-HALF, HALF]
OUT_UNIVERSE = 3.0  # output universe [0, 3], set j centred at j / 2 (Fig. 8)
OUT_ZO = OUT_UNIVERSE / 2

# Fig. 7 as printed: rows e = PB, PM, PS, ZO, NS, NM, NB; columns ec = PB, PM, PS, ZO, NS, NM, NB.
# (The ki table's column header "P" is read as PM. Two kp entries, e = PM with ec = NS and NB, are
# PS where the usual table has NS and NB; they are kept as printed.)
KP_PRINTED = """
NB NB NM NM NS ZO ZO
NB NM NM NM PS ZO PS
NM NM NS NS ZO PS PS
NM NM NS ZO PS PM PM
NS NS ZO PS PM PM PM
NS ZO PS PS PM PB PB
ZO ZO PS PM PM PB PB
"""
KI_PRINTED = """
PB PB PM PS PS ZO ZO
PB PB PM PS PS ZO ZO
PB PM PS PS ZO NS NM
PM PM PS ZO NS NM NM
PS PS ZO NS NS NM NB
ZO ZO NS NM NM NB NB
ZO ZO NS NM NM NB NB
"""
KD_PRINTED = """
PB PS PS PM PM PM PB
PB PS PS PS PS ZO PB
ZO ZO ZO ZO ZO ZO ZO
ZO NS NS NS NS NS ZO
ZO NS NS NS NM NM NS
ZO NS NM NM NB NS PS
ZO NM NB NB NB NS PS
"""


def parse_rule_table(printed: str) -> tuple[tuple[int, ...], ...]:
    """A printed table (rows e PB..NB, columns ec PB..NB) as ``table[e_set][ec_set]``, NB = 0."""
    rows = [line.split() for line in printed.strip().splitlines()]
    if len(rows) != N_SETS or any(len(row) != N_SETS for row in rows):
        raise ValueError(f"a rule table needs {N_SETS} rows of {N_SETS} labels")
    return tuple(tuple(LABELS.index(rows[N_SETS - 1 - e][N_SETS - 1 - ec]) for ec in range(N_SETS))
                 for e in range(N_SETS))


RULES = tuple(parse_rule_table(t) for t in (KP_PRINTED, KI_PRINTED, KD_PRINTED))  # kp, ki, kd

# Section 3: "量化因子 e 为 0.4, ec 取 0.6, 比例因子 kp、ki 和 kd 均取 1".
SEED001_KE_PER_C = 0.4
SEED001_KEC_S_PER_C = 0.6
SPAN_MAX = 1.0  # incremental corrections up to +-100 % of the base gains
DEFAULT_SPAN = 0.5

# Integer formats.
POS_BITS = 8  # universe positions and degrees: Q8
POS_ONE = 1 << POS_BITS
POS_MAX = HALF << POS_BITS  # 768
GRID = 8  # output grid points per set step (16 per unit of the [0, 3] universe)
GRID_MAX = (N_SETS - 1) * GRID  # 48
FACTOR_BITS = 12  # gain factors Q12; the centroid in Q12 units is num * 256 / den on the grid
K_BITS = 12  # ke and kec-per-sample: Q12
SPAN_BITS = 4  # span: Q4
OUT_FRAC_BITS = 8
OUT_MAX_Q8 = PID_MAX << OUT_FRAC_BITS
K_MAX = 100.0  # ke (1/degC) and kec (s/degC) domain: far beyond a sensible quantisation factor
P_SHIFT = KP_FRAC_BITS + FACTOR_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS
I_SHIFT = KI_FRAC_BITS + FACTOR_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS
D_SHIFT = KD_FRAC_BITS + FACTOR_BITS + TEMP_FRAC_BITS - OUT_FRAC_BITS
POS_SHIFT = K_BITS + TEMP_FRAC_BITS - POS_BITS


@dataclass(frozen=True)
class FuzzyPidConfig:
    """Quantisation factors and the reading of the tables.

    ``ke`` must be a multiple of 1/4096 for the integer port to hold it exactly (the paper's 0.4
    is not: ``SEED001_BOARD`` uses 1638/4096 = 0.39990); ``kec`` is per degC/s and is rounded per
    control sample by the integer port. ``span`` (incremental reading) is a multiple of 1/16.
    """

    ke: float = SEED001_KE_PER_C  # 1/degC: e -> universe [-3, 3]
    kec: float = SEED001_KEC_S_PER_C  # s/degC: de/dt -> universe [-3, 3]
    reading: str = LITERAL
    span: float = DEFAULT_SPAN  # incremental: the gains move by up to +-span of the base

    def __post_init__(self) -> None:
        for name in ("ke", "kec"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and 0 < value <= K_MAX):
                raise ValueError(f"{name} must be a number in (0, {K_MAX:g}], got {value!r}")
        if self.reading not in READINGS:
            raise ValueError(f"reading must be one of {', '.join(READINGS)}, got {self.reading!r}")
        span_q = self.span * (1 << SPAN_BITS) if isinstance(self.span, (int, float)) else math.nan
        if not (math.isfinite(span_q) and span_q == int(span_q) and 0 <= self.span <= SPAN_MAX):
            raise ValueError(f"span must be a multiple of 1/{1 << SPAN_BITS} in 0..{SPAN_MAX:g}, got {self.span!r}")


SEED001 = FuzzyPidConfig()  # the paper's loop, literal reading
SEED001_BOARD = FuzzyPidConfig(ke=1638 / 4096, reading=INCREMENTAL)  # the board build: Marlin's gains corrected


# -- the fuzzy system in float (the paper's) ----------------------------------------------------


SET_CENTRES = np.arange(N_SETS) - HALF
GRID_Y = np.arange(GRID_MAX + 1) / (2 * GRID)  # the output grid on [0, 3], 16 points a unit
# OUT_SETS[j, i]: degree of output set j (a triangle centred j/2, half-width 1/2) at grid point i
OUT_SETS = np.maximum(0.0, 1.0 - np.abs(GRID_Y[None, :] - SET_CENTRES[:, None] / 2 - OUT_ZO) * 2)
RULE_INDEX = [np.array(table).ravel() for table in RULES]  # output set of rule (e, ec), row-major


def memberships(x: float) -> np.ndarray:
    """Degrees of NB..PB at position x of [-3, 3]: unit triangles centred -3..3 (sum to 1)."""
    return np.maximum(0.0, 1.0 - np.abs(x - SET_CENTRES))


def centroid(strengths: np.ndarray) -> float:
    """Sampled centroid on [0, 3] of the max of the output sets clipped at their strengths."""
    mu = np.minimum(np.asarray(strengths, dtype=float)[:, None], OUT_SETS).max(axis=0)
    return float(GRID_Y @ mu / mu.sum())


def infer(x_e: float, x_ec: float) -> tuple[float, float, float]:
    """Mamdani min-max inference and centroid: the (kp, ki, kd) centroids in [0, 3]."""
    fired = np.minimum.outer(memberships(x_e), memberships(x_ec)).ravel()  # rule (e, ec) strengths
    out = []
    for index in RULE_INDEX:
        strengths = np.zeros(N_SETS)
        np.maximum.at(strengths, index, fired)
        out.append(centroid(strengths))
    return out[0], out[1], out[2]


def factor(c: float, config: FuzzyPidConfig) -> float:
    """The multiplier of a base gain for a centroid c in [0, 3], in the configured reading."""
    return c if config.reading == LITERAL else 1.0 + config.span * (c - OUT_ZO) / OUT_ZO


def check_non_negative(gains: PidGains) -> None:
    """The fuzzy-PID's widths are derived for base gains >= 0 (the paper's); ValueError otherwise."""
    negative = [name for name, value in vars(gains).items() if value < 0]
    if negative:
        raise ValueError(f"the fuzzy-PID takes base gains >= 0, not {', '.join(negative)} < 0")


class FuzzyPidFloat:
    """The fuzzy-PID in float64: the paper's loop (``step``), and the board interface (``update``)."""

    check_interval_ms = None

    def __init__(self, gains: PidGains = HOTEND_GAINS, config: FuzzyPidConfig = SEED001_BOARD, *,
                 dt_s: float = float(PID_DT_S), out_max: float | None = float(PID_MAX),
                 rounded: bool = False) -> None:
        self.config = config
        self.dt_s = dt_s
        self.out_max = out_max
        self.rounded = rounded  # use the integer port's rounded constants (its oracle)
        self.set_gains(gains)

    @classmethod
    def board(cls, gains: PidGains = HOTEND_GAINS, config: FuzzyPidConfig = SEED001_BOARD) -> FuzzyPidFloat:
        """The oracle of ``FuzzyPid``: its rounded constants, the board's period and 0..255 output."""
        return cls(gains, config, rounded=True)

    def __repr__(self) -> str:
        return f"FuzzyPidFloat({self.gains!r}, {self.config!r})"

    def set_gains(self, gains: PidGains) -> None:
        """Base gains (M301): kp, ki per second, kd in seconds; resets the loop."""
        check_non_negative(gains)
        self.gains = gains
        kp, ki, kd = gains.kp, gains.ki, gains.kd
        self.ke, self.kec = self.config.ke, self.config.kec
        if self.rounded:
            q = FixedConstants.of(self.config, gains)
            dt = self.dt_s
            self.ke = q.ke_q12 / (1 << K_BITS)
            self.kec = q.kec_ps_q12 / (1 << K_BITS) * dt
            kp, ki, kd = (q.kp_q12 / (1 << KP_FRAC_BITS), q.ki_q24 / (1 << KI_FRAC_BITS) / dt,
                          q.kd_q16 / (1 << KD_FRAC_BITS) * dt)
        self.kp, self.ki, self.kd = float(kp), float(ki), float(kd)
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the previous error."""
        self.i_term = 0.0
        self.e_prev = 0.0
        self.have_prev = False
        self.factors = (0.0, 0.0, 0.0)

    def step(self, e: float) -> float:
        """One control period on the error e: the output (saturated to 0..out_max if set)."""
        ec = (e - self.e_prev) / self.dt_s if self.have_prev else 0.0
        self.e_prev, self.have_prev = e, True
        x_e = min(max(self.ke * e, -HALF), HALF)
        x_ec = min(max(self.kec * ec, -HALF), HALF)
        f_p, f_i, f_d = (factor(c, self.config) for c in infer(x_e, x_ec))
        self.factors = (f_p, f_i, f_d)
        self.i_term += self.ki * f_i * e * self.dt_s
        p, d = self.kp * f_p * e, self.kd * f_d * ec
        if self.out_max is None:
            return p + self.i_term + d
        self.i_term = min(max(self.i_term, 0.0), self.out_max)
        return min(max(p + self.i_term + d, 0.0), self.out_max)

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """Board interface: output 0..255 (truncated, as ``(int)out`` in C); target 0 switches off."""
        if target_c == 0:
            self.reset()
            return 0
        return math.floor(self.step(target_c - temp_q5 / TEMP_ONE))


# -- the integer port ------------------------------------------------------------------------


@dataclass(frozen=True)
class FixedConstants:
    """Configuration-time integers of the port (a C const struct, or RAM for the gains)."""

    ke_q12: int  # uint32 Q12 1/degC, <= 409600
    kec_ps_q12: int  # uint32 Q12 per degC per sample: kec / dt
    span_q4: int  # uint8 Q4
    kp_q12: int  # int32, as PidFixed
    ki_q24: int  # int32, Ki * dt
    kd_q16: int  # int32, Kd / dt

    @classmethod
    def of(cls, config: FuzzyPidConfig, gains: PidGains) -> FixedConstants:
        kec_ps_q12 = max(1, q_scaled(config.kec, 1 / PID_DT_S, K_BITS))
        return cls(q_scaled(config.ke, Fraction(1), K_BITS), kec_ps_q12, round(config.span * (1 << SPAN_BITS)),
                   KP_Q12(gains.kp), KI_Q24(gains.ki), KD_Q16(gains.kd))


def _position_q8(value_q5: int, k_q12: int) -> int:
    """Quantisation onto the universe, Q8, saturated to [-3, 3]: int64 product (<= 2**34)."""
    return clamp(shr_round(checked_s64(value_q5 * k_q12), POS_SHIFT), -POS_MAX, POS_MAX)


def _fuzzify_q8(x_q8: int) -> list[tuple[int, int]]:
    """The (set, Q8 degree) pairs with a non-zero degree at x: one set or two neighbours."""
    left = min((x_q8 + POS_MAX) >> POS_BITS, N_SETS - 1)  # the set centred at or left of x
    pairs = []
    for k in (left, left + 1):
        if k < N_SETS:
            mu_q8 = POS_ONE - abs(x_q8 - ((k - HALF) << POS_BITS))  # uint16, Q8
            if mu_q8 > 0:
                pairs.append((k, mu_q8))
    return pairs


def centroid_q12(strengths_q8: list[int]) -> int:
    """The sampled centroid in Q12 units of [0, 3]: num <= 48*49/2*256 < 2**19, num << 8 < 2**27."""
    num = den = 0  # int32
    for y in range(GRID_MAX + 1):
        mu_q8 = 0  # uint16: the aggregated output degree at grid point y
        for j, s_q8 in enumerate(strengths_q8):
            if s_q8:
                mu_q8 = max(mu_q8, min(s_q8, max(0, GRID - abs(y - j * GRID)) << (POS_BITS - 3)))
        num += y * mu_q8
        den += mu_q8
    # c = y / 16 units; Q12: y * 256 (den >= 3.25 * 256: some rule fires at >= 1/2)
    return div_round(checked_s32(num << POS_BITS), den)


class FuzzyPid:
    """Integer fuzzy-PID: what the ATmega328 runs, ints and fixed.py helpers only per sample.

    State (C struct, 7 bytes): i_q8 int32 (Q8 counts, 0..65280), e_prev_q5 int16, have_prev
    uint8. Constants: ke, kec per sample (uint32 each), span (uint8), kp, ki, kd (int32 each),
    reading (uint8); rule tables 3 x 49 uint8 in flash.
    """

    check_interval_ms = None

    def __init__(self, gains: PidGains = HOTEND_GAINS, config: FuzzyPidConfig = SEED001_BOARD) -> None:
        self.config = config
        self.literal = config.reading == LITERAL  # uint8 flag
        self.set_gains(gains)

    def __repr__(self) -> str:
        return f"FuzzyPid({self.gains!r}, {self.config!r})"

    def set_gains(self, gains: PidGains) -> None:
        """M301: the base gains, rounded as PidFixed rounds them; resets the loop."""
        check_non_negative(gains)
        self.gains = gains
        self.k = FixedConstants.of(self.config, gains)
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the previous error (Marlin's pid_reset)."""
        self.i_q8 = 0
        self.e_prev_q5 = 0
        self.have_prev = 0
        self.factors_q12 = (0, 0, 0)

    def factor_q12(self, c_q12: int) -> int:
        """Gain factor Q12: c itself (literal) or 1 + span (c - 1.5) / 1.5 (incremental), 0..12288."""
        if self.literal:
            return c_q12
        return (1 << FACTOR_BITS) + div_round(checked_s32(self.k.span_q4 * (c_q12 - (3 << (FACTOR_BITS - 1)))),
                                              24)  # Q4 * Q12 / (1.5 * 16)

    def infer_q12(self, e_q5: int, derr_q5: int) -> tuple[int, int, int]:
        """The three gain factors (Q12) for an error and its change over one sample."""
        e_sets = _fuzzify_q8(_position_q8(e_q5, self.k.ke_q12))
        ec_sets = _fuzzify_q8(_position_q8(derr_q5, self.k.kec_ps_q12))
        out = []
        for table in RULES:
            strengths_q8 = [0] * N_SETS  # uint16[7]
            for i, mu_e in e_sets:
                for j, mu_ec in ec_sets:
                    k = table[i][j]
                    strengths_q8[k] = max(strengths_q8[k], min(mu_e, mu_ec))
            out.append(self.factor_q12(centroid_q12(strengths_q8)))
        return out[0], out[1], out[2]

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """One step on a fresh reading; returns 0..255 (the soft PWM gets ``>> 1``)."""
        return self.update_q8(temp_q5, target_c) >> OUT_FRAC_BITS

    def update_q8(self, temp_q5: int, target_c: int) -> int:
        """The law with its Q8 output (0..65280)."""
        if target_c == 0:
            self.reset()
            return 0
        e_q5 = sat_s16((target_c << TEMP_FRAC_BITS) - temp_q5)  # int16 (saturated)
        derr_q5 = sat_s16(e_q5 - self.e_prev_q5) if self.have_prev else 0  # int16 (saturated)
        self.e_prev_q5, self.have_prev = e_q5, 1
        f_p, f_i, f_d = self.factors_q12 = self.infer_q12(e_q5, derr_q5)
        k = self.k
        # kp_q12 <= 2**22, factor <= 3 * 2**12, |e| <= 2**15: int64 < 2**51; Q29 -> Q8 < 2**30.
        p_q8 = checked_s32(shr_round(checked_s64(k.kp_q12 * f_p * e_q5), P_SHIFT))
        # ki_q24 <= 2**28: int64 < 2**57; Q41 -> Q8 < 2**24; the sum is clamped (anti-windup).
        di_q8 = checked_s32(shr_round(checked_s64(k.ki_q24 * f_i * e_q5), I_SHIFT))
        self.i_q8 = clamp(checked_s32(self.i_q8 + di_q8), 0, OUT_MAX_Q8)
        # kd_q16 < 2**31: int64 < 2**60; Q33 -> Q8 may exceed int32: saturated (the output clamps anyway).
        d_q8 = sat_s32(shr_round(checked_s64(k.kd_q16 * f_d * derr_q5), D_SHIFT))
        # p + i + d can reach 2**31.6: summed in int64, then clamped to the output range.
        return clamp(checked_s64(p_q8 + self.i_q8 + d_q8), 0, OUT_MAX_Q8)


# -- the compiled batch's lane law (firmware_port/lane_law.py) --------------------------------------
GRID_SHIFT = POS_BITS - 3  # a grid degree (0..8) to Q8
ZO_Q12 = 3 << (FACTOR_BITS - 1)  # the output universe's middle, 1.5, in Q12
SPAN_DIVISOR = 3 << (SPAN_BITS - 1)  # 1.5 in the span's Q4: span (c - 1.5) / 1.5
LANE_PARAMS = record_dtype(("ke_q12", "kec_ps_q12", "span_q4", "kp_q12", "ki_q24", "kd_q16", "literal"))
LANE_STATE = ("i_q8", "e_prev_q5", "have_prev")  # FuzzyPid's state
# ``strengths_q8``: the inference's scratch, one output degree per set (the AVR's 7 uint16 on the stack).
LANE_STATE_DTYPE = np.dtype([(name, np.int64) for name in LANE_STATE] + [("strengths_q8", np.int64, (N_SETS,))])
RULE_ARRAY = np.array(RULES, dtype=np.int64)  # [table, e set, ec set]: the output set (frozen into the compiled law)
RULE_ARRAY.flags.writeable = False


def _fuzzify_lane(x_q8: int) -> tuple[int, int, int, int]:
    """``_fuzzify_q8`` as (set, degree) twice; the second degree 0 when absent."""
    left = min((x_q8 + POS_MAX) >> POS_BITS, N_SETS - 1)
    k0, mu0, k1, mu1 = -1, 0, -1, 0
    for k in (left, left + 1):
        if k < N_SETS:
            mu = POS_ONE - abs(x_q8 - ((k - HALF) << POS_BITS))
            if mu > 0:
                if k0 < 0:
                    k0, mu0 = k, mu
                else:
                    k1, mu1 = k, mu
    return k0, mu0, k1, mu1


def _centroid_lane(strengths_q8) -> int:
    """``centroid_q12`` over the support of the fired sets (elsewhere every degree is 0)."""
    y_lo, y_hi = GRID_MAX, 0
    for j in range(N_SETS):
        if strengths_q8[j]:
            y_lo, y_hi = min(y_lo, max(0, (j - 1) * GRID)), max(y_hi, min(GRID_MAX, (j + 1) * GRID))
    num = den = 0
    for y in range(y_lo, y_hi + 1):
        mu = 0
        for j in range(N_SETS):
            if strengths_q8[j]:
                mu = max(mu, min(strengths_q8[j], max(0, GRID - abs(y - j * GRID)) << GRID_SHIFT))
        num += y * mu
        den += mu
    return div_round(num << POS_BITS, den)


def fuzzy_pid_lane(p, s, temp_q5, target_c, board):
    """``FuzzyPid.update`` on one lane of the compiled batch: the fuzzy-corrected gains, then the PID."""
    if target_c == 0:
        s.i_q8, s.e_prev_q5, s.have_prev = 0, 0, 0
        return 0
    e = clamp((target_c << TEMP_FRAC_BITS) - temp_q5, -32768, 32767)
    derr = clamp(e - s.e_prev_q5, -32768, 32767) if s.have_prev else 0
    s.e_prev_q5, s.have_prev = e, 1
    ek0, emu0, ek1, emu1 = _fuzzify_lane(clamp(shr_round(e * p.ke_q12, POS_SHIFT), -POS_MAX, POS_MAX))
    dk0, dmu0, dk1, dmu1 = _fuzzify_lane(clamp(shr_round(derr * p.kec_ps_q12, POS_SHIFT), -POS_MAX, POS_MAX))
    strengths = s.strengths_q8
    f_p = f_i = f_d = 0
    for t in range(3):
        for j in range(N_SETS):
            strengths[j] = 0
        for a in range(2):
            i, mu_e = (ek0, emu0) if a == 0 else (ek1, emu1)
            if mu_e == 0:
                continue
            for b in range(2):
                c, mu_d = (dk0, dmu0) if b == 0 else (dk1, dmu1)
                if mu_d == 0:
                    continue
                k = RULE_ARRAY[t, i, c]
                strengths[k] = max(strengths[k], min(mu_e, mu_d))
        c_q12 = _centroid_lane(strengths)
        factor = c_q12 if p.literal else (1 << FACTOR_BITS) + div_round(p.span_q4 * (c_q12 - ZO_Q12), SPAN_DIVISOR)
        if t == 0:
            f_p = factor
        elif t == 1:
            f_i = factor
        else:
            f_d = factor
    p_q8 = shr_round(p.kp_q12 * f_p * e, P_SHIFT)
    s.i_q8 = clamp(s.i_q8 + shr_round(p.ki_q24 * f_i * e, I_SHIFT), 0, OUT_MAX_Q8)
    d_q8 = clamp(shr_round(p.kd_q16 * f_d * derr, D_SHIFT), -(1 << 31), (1 << 31) - 1)
    return clamp(p_q8 + s.i_q8 + d_q8, 0, OUT_MAX_Q8) >> OUT_FRAC_BITS


def _lane_params(lanes) -> np.ndarray:
    """The lanes' constants: each controller's ``FixedConstants`` and its reading."""
    out = attributes([c.k for c in lanes.controllers], LANE_PARAMS, field_names(LANE_PARAMS)[:-1])
    out["literal"] = [c.literal for c in lanes.controllers]
    return out


# Every parameter is read from the first reading with a target: lanes share a heat-up only with their twins.
FUZZY_PID_LAW = register(LaneLaw(
    "fuzzy_pid", FuzzyPid, LANE_PARAMS, LANE_STATE_DTYPE, fuzzy_pid_lane,
    pack=_lane_params, read=lambda lanes: attributes(lanes.controllers, LANE_STATE_DTYPE, LANE_STATE),
    write=lambda lanes, state: set_attributes(lanes.controllers, state, LANE_STATE)), check=False)


SEARCH_FACTOR = 8.0  # tuning bounds: each base gain from 0 to 8 x the build's default


def fuzzy_pid_space(default: PidGains = HOTEND_GAINS, integer: bool = True) -> ParamSpace:
    """Seed 001's controller on the board as a tunable family: its base gains Kp, Ki, Kd (M301 units)
    under the board build's incremental fuzzy correction, each from 0 to ``SEARCH_FACTOR`` x its default."""
    tops = (KP_MAX, KI_MAX, KD_MAX)
    units = ("counts/C", "counts/(C s)", "counts s/C")
    params = tuple(Param(name, unit, 0.0, min(SEARCH_FACTOR * value, top) or top, value)
                   for name, unit, value, top in zip(("kp", "ki", "kd"), units,
                                                     (default.kp, default.ki, default.kd), tops))

    def factory(kp: float, ki: float, kd: float) -> FuzzyPid | FuzzyPidFloat:
        gains = PidGains(kp, ki, kd)
        return FuzzyPid(gains) if integer else FuzzyPidFloat.board(gains)

    return ParamSpace("fuzzy_pid" if integer else "fuzzy_pid_float", params, factory, autotune="M303")


# RAM and flash on the AVR, as C structs lay them out (uint8 1, int16 2, int32 4).
STATE_FIELDS = (("i_q8", 4), ("e_prev_q5", 2), ("have_prev", 1))
CONFIG_FIELDS = (("ke_q12", 4), ("kec_ps_q12", 4), ("span_q4", 1), ("reading", 1),
                 ("kp_q12", 4), ("ki_q24", 4), ("kd_q16", 4))
RULE_TABLE_BYTES = len(RULES) * N_SETS * N_SETS  # uint8 labels, flash


def ram_report() -> dict[str, int]:
    """Bytes one heater's fuzzy-PID takes on the ATmega328.

    ============================  =====  ==============================================
    state (RAM)                       7  i_q8 4, e_prev_q5 2, have_prev 1
    config and gains (RAM)           22  ke 4, kec 4, span 1, reading 1, kp ki kd 4+4+4
    rule tables (flash)             147  3 x 7 x 7 uint8 labels
    per-update scratch (stack)       14  7 uint16 strengths
    ============================  =====  ==============================================

    Set breakpoints and the output grid are shifts and constants: no membership tables.
    """
    return {
        "state_bytes": sum(size for _, size in STATE_FIELDS),
        "config_bytes": sum(size for _, size in CONFIG_FIELDS),
        "table_bytes": RULE_TABLE_BYTES,
        "stack_bytes": 2 * N_SETS,
    }
