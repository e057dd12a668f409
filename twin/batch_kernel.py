"""The batch twin's control periods as one compiled loop per lane (numba), for speed.

``BatchTwin`` runs N hotend twins as numpy lanes (``firmware_port.marlin.lanes``): every control
period costs some fifty numpy calls on N-element arrays, so the interpreter, not the
arithmetic, sets the pace. Here the same period (soft-PWM pulses, the sensor samples through the
plant's exact tick maps, the ADC sums, ``updateTemperaturesFromRawValues`` and
``manage_hotends``: protection and the controller) runs lane by lane over a whole stretch
between scenario events, each lane's state in one cache line or two. What a lane can run:

- controllers: Marlin's fixed-point PID (either prev-temperature mode), bang-bang, seed 004's
  fuzzy-like PI and seed 001's fuzzy-PID, each the integer law of its scalar class
  (firmware_port), one family per batch, parameters per lane;
- the ADC: a noiseless chain through a table of switching temperatures (``twin.adc_table``), or a
  noisy one: ``floor(analog + noise)`` with the noise drawn outside (one stream per seed, shared
  by the lanes that name it) and the analog value taken from a straight line between the edges
  unless the noisy value lies within the line's error bound of an integer, when it is computed
  from the thermistor's formula (about 0.5 % of the samples at 210 C);
- the plant: a linear model's exact tick maps; a dead time as a ring of the lane's past heater
  pulses (exact on the tick grid: the plant sees the pulses ``delay`` ticks late); a radiating
  model as the scalar engine runs it, relinearised at the block's 0.5 C bin before every period,
  one table of maps per bin. A lane that reaches a bin outside the tables stops where it is
  (``stop``, ``need_bin``) and resumes after ``BatchTwin`` has built it;
- records per reading (optional) and, streaming, what the heater objective needs (``score_*``):
  memory per lane independent of the horizon.

Same results as the numpy lanes, bit for bit where those run (linear plants without dead time):
the firmware is integer arithmetic (``//`` and ``>>`` floor in numba as in numpy); the plant's
float arithmetic is written in the same order of operations here as in ``BatchTwin``'s numpy
period, without fused multiply-adds (numba does not contract without fastmath), and the ADC uses
the same table of switching temperatures. A noisy sample's analog value, when it must be
computed, comes from libm's ``exp``, which may differ from numpy's (SIMD) ``exp`` in the last bit:
that changes a count only when the noisy value lies within 1e-13 of an integer, never seen in the
tests (tests/twin/test_batch_paths.py, tests/firmware_port/marlin/test_lanes.py).

``HEATER_TWIN_KERNEL`` picks the implementation: ``numba`` (default when numba is installed,
``pip install heater-twin[fast]``) or ``numpy``. Without numba, ``BatchTwin(kernel="numba")``
still runs the loop below as plain Python: slow, but the tests check the same code that way.
The loop releases the GIL, so ``BatchTwin`` spreads lanes over threads.
"""

from __future__ import annotations

import os

import numpy as np

from firmware_port.fuzzy_pid import FACTOR_BITS as FP_FACTOR_BITS, GRID as FP_GRID, GRID_MAX as FP_GRID_MAX, \
    HALF as FP_HALF, N_SETS as FP_SETS, POS_BITS as FP_POS_BITS, SPAN_BITS as FP_SPAN_BITS
from firmware_port.marlin.constants import MIN_ADC_ISR_LOOPS, TICKS_PER_READING  # frozen in: constant divisors
from firmware_port.marlin.pid import D_FILTER_DIVISOR  # 20: frozen into the code, a constant divisor is a multiply
from firmware_port.marlin.lanes import (
    FIRST_HEATING,
    INACTIVE,
    MAXTEMP_TRIP,
    MINTEMP_TRIP,
    RUNAWAY,
    RUNAWAY_TRIP,
    STABLE,
    WATCH_TRIP,
)
from twin.numba_cache import cached_njit

try:
    import numba
except ImportError:  # the optional `fast` extra
    numba = None  # type: ignore[assignment]

KERNELS = ("numba", "numpy")
KERNEL_ENV = "HEATER_TWIN_KERNEL"

# Per-lane integer state, the columns of ``istate`` (N, N_STATE). C0..C3: the controller's state
# (PID: i_sum_q5, d_term_q8, prev_q5, reset_pending; fuzzy PI: duty_q16, err_prev_q5, have_prev;
# fuzzy-PID: i_q8, e_prev_q5, have_prev). R_PENDING: the target changed since the lane's last
# reading (the runaway monitor restarts). RING_HEAD, RING_LEN: the dead-time ring of pulses.
(AMOUNT, COUNT, PINS, TEMP, HALTED, TRIP, R_STATE, R_TIMER, W_TARGET, W_NEXT, C0, C1, C2, C3, ACC, HINT,
 R_PENDING, RING_HEAD, RING_LEN) = range(19)
N_STATE = 19
# Controllers, ``fw[CONTROL]``, and their per-lane constants, the columns of ``cparams`` (N, N_CPARAMS).
PID, BANG_BANG, FUZZY_PI, FUZZY_PID = range(4)
KP, KI, KD, I_MAX, EVERY = range(5)  # PID: PidFixed's scales; EVERY: prev temperature on every sample
N_SETS, ERR_RANGE, DERR_RANGE, DU_RANGE, OUT_MAX = range(5)  # fuzzy PI: FuzzyPi's fields
KE, KEC, SPAN, FKP, FKI, FKD, LITERAL = range(7)  # fuzzy-PID: FixedConstants, reading literal
N_CPARAMS = 8
# Per family, the ``cparams`` columns its law reads where ``_tuned`` is false: lanes that agree on these
# and on their state run the same periods up to their first tuned reading (``BatchTwin``'s shared prefix):
# a PID's heat-up at full power; a bang-bang's whole run; a fuzzy controller's only with its very twin.
UNTUNED_PARAMS = {PID: (EVERY,), BANG_BANG: (), FUZZY_PI: tuple(range(N_CPARAMS)), FUZZY_PID: tuple(range(N_CPARAMS))}
# Firmware constants, the entries of ``fw``: passed in, not frozen into the cached machine code.
(TARGET, RAW_MAX, RAW_MIN, MINTEMP_Q5, MAXTEMP_Q5, R_PERIOD_MS, R_HYST_C, W_INC_C, W_HYST_C, W_PERIOD_MS,
 P_SHIFT, I_SHIFT, D_SHIFT, D_LIMIT_Q8, RANGE_Q5, OUT_MAX_Q8, OUT_FRAC_BITS, TEMP_FRAC_BITS,
 PWM_PERIOD, ADC_MAX, CONTROL, BANG_MAX, DELAY, BIN_LO, RADIATING, RECORD, SCORE, SKIP_ROWS,
 ROW_BASE, FZ_BR_BITS, FZ_GRID_BITS, FZ_CENTROID_BITS, FZ_DUTY_BITS, FP_POS_SHIFT, FP_P_SHIFT, FP_I_SHIFT,
 FP_D_SHIFT, PROBE) = range(38)
N_FW = 38  # PROBE: stop a lane at its first reading whose control reads the lane's own parameters (``_tuned``)
PROBED = -(1 << 62)  # ``need_bin`` of a lane the probe stopped (not a bin: no block is that cold)
# The plan of a stretch, one row per period: its columns.
(N_TICKS, FIRST_SAMPLE, READING, PWM_COUNT, MILLIS, KIND, TICK, ROW, FLAGS, Z_FIRST, FIRST_WRAP,
 LAST_PHASE) = range(12)
PLAN_COLUMNS = 12
SCORED, HEAT, LAST_HEAT = 1, 2, 4  # FLAGS bits of a reading row: after the skipped rows, in the heat-up, its last
# The heater objective's inputs per lane, streamed: floats ``score_f`` and integers ``score_i``.
MAX_BEYOND, ABS_ERROR_SUM, DUTY_STEP_SUM, PREV_DUTY = range(4)
HOLDING, REACHED, FIRST_ROW, HOLD_ROWS = range(4)
N_SCORE = 4
# ``score_p``: target_c, the heat-up's sign (+1 heating), the band (degC).
S_TARGET, S_SIGN, S_BAND = range(3)
# ``sensor_p``: the thermistor's beta model for a noisy sample's analog value.
SP_C1, SP_C2, SP_KELVIN, SP_PULLUP, SP_COUNTS = range(5)
UNROLLED_STATES = 3  # the plant size whose loops are compiled unrolled (hotend_stock, hotend_cartridge)
MAX_PULSES = 4  # a run of <= 160 ticks holds the tail of a pulse and at most two 127-tick wraps (and a spare)
ROW_OFFSET = TICKS_PER_READING  # ``rows``: row o + ROW_OFFSET is the sensor step at each sample, o = s0 - pulse edge
CHORD_MARGIN_C = 1e-9  # the chord shortcut's band: beyond the float rounding of a sample (about 1e-12 C)


def default_kernel() -> str:
    """The kernel ``HEATER_TWIN_KERNEL`` names, else numba when installed; ValueError names a bad value."""
    kernel = os.environ.get(KERNEL_ENV, "numba" if numba is not None else "numpy")
    if kernel not in KERNELS:
        raise ValueError(f"{KERNEL_ENV}={kernel!r}: must be one of {', '.join(KERNELS)}")
    if kernel == "numba" and numba is None:
        raise ValueError(f"{KERNEL_ENV}=numba: numba is not installed (pip install 'heater-twin[fast]')")
    return kernel


def compiled() -> bool:
    """Whether the loop below runs as machine code (numba installed)."""
    return numba is not None


def describe() -> str:
    return f"numba {numba.__version__}" if numba is not None else "numba not installed"


# The loop allocates nothing (its scratch arrays come in), so it runs without numba's reference
# counting: passing arrays to the inlined helpers would otherwise cost an atomic increment and
# decrement each, per period, more than the arithmetic (0.96 s against 0.39 s of CPU for 1000
# lanes x 600 s on the 2-core reference machine). ``_nrt`` is numba's own switch for that runtime
# (underscored, so not promised: tests/firmware_port/marlin/test_lanes.py, run against numba in CI, would catch a change).
NUMBA_OPTIONS = {"_nrt": False, "error_model": "numpy"}


def jit(fn):
    """A kernel: compiled, cached (twin/numba_cache.py), releasing the GIL (BatchTwin runs lanes on threads)."""
    return cached_njit(fn, nogil=True, **NUMBA_OPTIONS) if numba is not None else fn


def inline(fn):
    """A helper of a kernel, inlined into it."""
    return numba.njit(inline="always", **NUMBA_OPTIONS)(fn) if numba is not None else fn


@inline
def shr_round(x, n):
    return (x + (1 << (n - 1))) >> n


@inline
def div_round(a, b):
    """fixed.div_round for b > 0: nearest, halves away from zero."""
    half = b // 2
    return (a + half) // b if a >= 0 else -((-a + half) // b)


@inline
def _clamp(x, lo, hi):
    return lo if x < lo else hi if x > hi else x


@inline
def _wrap_s32(x):
    return ((x + (1 << 31)) & 0xFFFFFFFF) - (1 << 31)


@inline
def _trip(st, code):
    """_temp_error: heater off, board halted (once)."""
    if st[HALTED] == 0:
        st[TRIP], st[HALTED], st[AMOUNT], st[COUNT], st[PINS] = code, 1, 0, 0, 0


# -- the controllers -----------------------------------------------------------------------------
@inline
def _pid_band(st, temp, e, cp, fw):
    """The PID law inside the functional range; state kept in ``st``."""
    i_sum, d_term = (0, 0) if st[C3] else (st[C0], st[C1])
    i_sum = min(max(i_sum + e, 0), cp[I_MAX])
    p = shr_round(cp[KP] * e, fw[P_SHIFT])
    i = shr_round(cp[KI] * i_sum, fw[I_SHIFT])
    d_in = min(max(shr_round(cp[KD] * (st[C2] - temp), fw[D_SHIFT]), -fw[D_LIMIT_Q8]), fw[D_LIMIT_Q8])
    d_term = d_term + div_round(d_in - d_term, D_FILTER_DIVISOR)
    st[C0], st[C1], st[C2], st[C3] = i_sum, d_term, temp, 0
    return min(max(p + i + d_term, 0), fw[OUT_MAX_Q8])


@inline
def _in_band(e, target, fw):
    """Whether the PID's error e (Q5) lies in its functional range: the law that reads the gains."""
    return -fw[RANGE_Q5] <= e <= fw[RANGE_Q5] and target != 0


@inline
def _pid(st, temp, target, cp, fw):
    """``PidFixed.update_q8`` on one active lane: Q.8 output."""
    e = (target << fw[TEMP_FRAC_BITS]) - temp
    if _in_band(e, target, fw):
        return _pid_band(st, temp, e, cp, fw)
    st[C3] = 1
    if cp[EVERY]:
        st[C2] = temp
    return fw[OUT_MAX_Q8] if target != 0 and e > fw[RANGE_Q5] else 0


@inline
def _membership(pos, k, n_sets, br):
    """fuzzy_pi.membership: set k of n_sets at pos, in units of 1/br (outer sets trapezoids)."""
    centre = (k + 1) * br
    if (k == 0 and pos <= centre) or (k == n_sets - 1 and pos >= centre):
        return br
    return max(0, br - abs(pos - centre))


@inline
def _fuzzify(pos, n, fw):
    """fuzzy_pi._fuzzify: (first set, its degree, second set, its degree); a degree 0 when absent."""
    one = 1 << fw[FZ_BR_BITS]
    left = min((pos >> fw[FZ_BR_BITS]) - 1, n - 1)
    k0, mu0, k1, mu1 = -1, 0, -1, 0
    for k in (left, left + 1):
        if 0 <= k < n:
            mu = _membership(pos, k, n, one)
            if mu > 0:
                if k0 < 0:
                    k0, mu0 = k, mu
                else:
                    k1, mu1 = k, mu
    if k1 < 0:
        k1 = k0
    return k0, mu0, k1, mu1


@inline
def _normalise(value, value_range, n, fw):
    """FuzzyPi._normalise: eq. (1) on the integer axis, saturated."""
    half = (n + 1) << (fw[FZ_BR_BITS] - 1)
    value = _clamp(value, -value_range, value_range)
    return half + div_round(_wrap_s32(value * half), value_range)


@inline
def _fuzzy_pi_change(err, derr, cp, fw):
    """FuzzyPi.change_q16: min-max inference over the (at most four) fired rules, sampled centroid."""
    n = cp[N_SETS]
    ek0, emu0, ek1, emu1 = _fuzzify(_normalise(err, cp[ERR_RANGE], n, fw), n, fw)
    dk0, dmu0, dk1, dmu1 = _fuzzify(_normalise(derr, cp[DERR_RANGE], n, fw), n, fw)
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
    grid_bits = fw[FZ_GRID_BITS]
    grid = 1 << grid_bits
    shift = fw[FZ_BR_BITS] - grid_bits
    y_mid = (k_lo + k_hi + 2) << (grid_bits - 1)
    num = den = 0
    for y in range(k_lo << grid_bits, ((k_hi + 2) << grid_bits) + 1):
        mu = 0
        for k in range(k_lo, k_hi + 1):
            strength = s0 if k == k_lo else s1 if k == k_lo + 1 else s2
            mu = max(mu, min(strength, _membership(y, k, 2 * n - 1, grid) << shift))
        num += (y - y_mid) * mu
        den += mu
    offset = ((y_mid - n * grid) << fw[FZ_CENTROID_BITS]) + div_round(_wrap_s32(num << fw[FZ_CENTROID_BITS]), den)
    return div_round(_wrap_s32(offset * cp[DU_RANGE]), n)


@inline
def _fuzzy_pi(st, temp, target, cp, fw):
    """FuzzyPi.update: the duty (0..out_max counts) after this sample's change."""
    if target == 0:
        st[C0], st[C2] = 0, 0
        return 0
    err = (target << fw[TEMP_FRAC_BITS]) - temp
    derr = err - st[C1] if st[C2] else 0
    st[C1], st[C2] = err, 1
    change = _fuzzy_pi_change(err, derr, cp, fw)
    st[C0] = _clamp(st[C0] + change, 0, cp[OUT_MAX] << fw[FZ_DUTY_BITS])
    return shr_round(st[C0], fw[FZ_DUTY_BITS])


# The fuzzy-PID's shape (7 sets on [-3, 3] in Q8, an output grid of 8 points a set step) is frozen
# into the compiled code; its tuning constants come in ``fw`` and ``cparams``.
FP_POS_ONE = 1 << FP_POS_BITS
FP_POS_MAX = FP_HALF << FP_POS_BITS
FP_GRID_SHIFT = FP_POS_BITS - 3  # a grid degree (0..8) to Q8
FP_ZO_Q12 = 3 << (FP_FACTOR_BITS - 1)  # the output universe's middle, 1.5, in Q12
FP_SPAN_DIVISOR = 3 << (FP_SPAN_BITS - 1)  # 1.5 in the span's Q4: span (c - 1.5) / 1.5


@inline
def _fuzzify_q8(x):
    """fuzzy_pid._fuzzify_q8: (set, degree) twice; the second degree 0 when absent."""
    left = min((x + FP_POS_MAX) >> FP_POS_BITS, FP_SETS - 1)
    k0, mu0, k1, mu1 = -1, 0, -1, 0
    for k in (left, left + 1):
        if k < FP_SETS:
            mu = FP_POS_ONE - abs(x - ((k - FP_HALF) << FP_POS_BITS))
            if mu > 0:
                if k0 < 0:
                    k0, mu0 = k, mu
                else:
                    k1, mu1 = k, mu
    return k0, mu0, k1, mu1


@inline
def _centroid_q12(strengths):
    """fuzzy_pid.centroid_q12 over the support of the fired sets (elsewhere every degree is 0)."""
    y_lo, y_hi = FP_GRID_MAX, 0
    for j in range(FP_SETS):
        if strengths[j]:
            y_lo, y_hi = min(y_lo, max(0, (j - 1) * FP_GRID)), max(y_hi, min(FP_GRID_MAX, (j + 1) * FP_GRID))
    num = den = 0
    for y in range(y_lo, y_hi + 1):
        mu = 0
        for j in range(FP_SETS):
            if strengths[j]:
                mu = max(mu, min(strengths[j], max(0, FP_GRID - abs(y - j * FP_GRID)) << FP_GRID_SHIFT))
        num += y * mu
        den += mu
    return div_round(num << FP_POS_BITS, den)


@inline
def _fuzzy_pid(st, temp, target, cp, fw, rules, strengths):
    """FuzzyPid.update_q8: the fuzzy-corrected gains, then the PID with its clamped integral."""
    if target == 0:
        st[C0], st[C1], st[C2] = 0, 0, 0
        return 0
    e = _clamp((target << fw[TEMP_FRAC_BITS]) - temp, -32768, 32767)
    derr = _clamp(e - st[C1], -32768, 32767) if st[C2] else 0
    st[C1], st[C2] = e, 1
    ek0, emu0, ek1, emu1 = _fuzzify_q8(_clamp(shr_round(e * cp[KE], fw[FP_POS_SHIFT]), -FP_POS_MAX, FP_POS_MAX))
    dk0, dmu0, dk1, dmu1 = _fuzzify_q8(_clamp(shr_round(derr * cp[KEC], fw[FP_POS_SHIFT]), -FP_POS_MAX, FP_POS_MAX))
    f_p = f_i = f_d = 0
    for t in range(3):
        for j in range(FP_SETS):
            strengths[j] = 0
        for a in range(2):
            i, mu_e = (ek0, emu0) if a == 0 else (ek1, emu1)
            if mu_e == 0:
                continue
            for b in range(2):
                c, mu_d = (dk0, dmu0) if b == 0 else (dk1, dmu1)
                if mu_d == 0:
                    continue
                k = rules[t, i, c]
                strengths[k] = max(strengths[k], min(mu_e, mu_d))
        c_q12 = _centroid_q12(strengths)
        factor = c_q12 if cp[LITERAL] else (1 << FP_FACTOR_BITS) + div_round(cp[SPAN] * (c_q12 - FP_ZO_Q12), FP_SPAN_DIVISOR)
        if t == 0:
            f_p = factor
        elif t == 1:
            f_i = factor
        else:
            f_d = factor
    p = shr_round(cp[FKP] * f_p * e, fw[FP_P_SHIFT])
    st[C0] = _clamp(st[C0] + shr_round(cp[FKI] * f_i * e, fw[FP_I_SHIFT]), 0, fw[OUT_MAX_Q8])
    d = _clamp(shr_round(cp[FKD] * f_d * derr, fw[FP_D_SHIFT]), -(1 << 31), (1 << 31) - 1)
    return _clamp(p + st[C0] + d, 0, fw[OUT_MAX_Q8])


@inline
def _control(st, temp, target, cp, fw, rules, strengths):
    """The lane's controller's ``update``: its output on the 0..255 scale."""
    kind = fw[CONTROL]
    if kind == PID:
        return _pid(st, temp, target, cp, fw) >> fw[OUT_FRAC_BITS]
    if kind == BANG_BANG:
        return fw[BANG_MAX] if temp < target << fw[TEMP_FRAC_BITS] else 0
    if kind == FUZZY_PI:
        return _fuzzy_pi(st, temp, target, cp, fw)
    return _fuzzy_pid(st, temp, target, cp, fw, rules, strengths) >> fw[OUT_FRAC_BITS]


@inline
def _tuned(temp, target, fw):
    """Whether the lane's controller reads its own tuning at this reading, parameters beyond
    ``UNTUNED_PARAMS``: the PID in its band (the other families have every parameter there)."""
    return fw[CONTROL] == PID and _in_band((target << fw[TEMP_FRAC_BITS]) - temp, target, fw)


# -- protection and the main loop ---------------------------------------------------------------
@inline
def _runaway(st, temp, target, now, fw):
    """``RunawayMonitor.run``; R_PENDING: the target changed since the lane's last reading."""
    if st[R_PENDING] and st[HALTED] == 0:
        st[R_STATE] = FIRST_HEATING if target > 0 else INACTIVE
    st[R_PENDING] = 0
    state = st[R_STATE]
    if state == FIRST_HEATING and temp >= target << fw[TEMP_FRAC_BITS]:
        state = STABLE
    if state == STABLE:
        if temp >= (target - fw[R_HYST_C]) << fw[TEMP_FRAC_BITS]:
            st[R_TIMER] = now + fw[R_PERIOD_MS]
        elif now >= st[R_TIMER]:
            state = RUNAWAY
    st[R_STATE] = state
    if state == RUNAWAY:
        _trip(st, RUNAWAY_TRIP)


@inline
def _watch(st, temp, target, now, fw):
    """``HeaterWatch.heating_failed``: re-arm from the current temperature if risen enough, else trip."""
    if st[W_NEXT] == 0 or now < st[W_NEXT]:
        return
    whole_c = temp >> fw[TEMP_FRAC_BITS] if temp >= 0 else -((-temp) >> fw[TEMP_FRAC_BITS])
    if whole_c < st[W_TARGET]:
        _trip(st, WATCH_TRIP)
        return
    cur = whole_c + fw[W_INC_C]
    if target != 0 and cur < target - fw[W_HYST_C] - 1:
        st[W_TARGET], st[W_NEXT] = cur, now + fw[W_PERIOD_MS]
    else:
        st[W_NEXT] = 0


@inline
def _task(st, raw, now, lut, cp, fw, rules, strengths):
    """``HotendLanes.task`` on one lane with a fresh reading; True, having stopped before the control,
    when probing (``fw[PROBE]``) and the control would read the lane's tuning."""
    target = fw[TARGET]
    if st[HALTED] == 0:
        st[TEMP] = lut[raw]
        if raw < fw[RAW_MAX]:
            _trip(st, MAXTEMP_TRIP)
    temp = st[TEMP]
    if target > 0 and raw > fw[RAW_MIN]:
        _trip(st, MINTEMP_TRIP)
    if temp > fw[MAXTEMP_Q5]:
        _trip(st, MAXTEMP_TRIP)
    _runaway(st, temp, target, now, fw)
    in_range = st[HALTED] == 0 and fw[MINTEMP_Q5] < temp < fw[MAXTEMP_Q5]
    if fw[PROBE] and in_range and _tuned(temp, target, fw):
        return True
    st[AMOUNT] = _control(st, temp, target, cp, fw, rules, strengths) >> 1 if in_range else 0
    _watch(st, temp, target, now, fw)
    return False


# -- the soft PWM and the plant -------------------------------------------------------------------
@inline
def _pulses(st, pwm, first_wrap, n, fw, alpha, beta):
    """``HotendLanes.pulses``: the heater is on over ticks [alpha, beta); returns how many pulses.
    ``first_wrap``: the soft-PWM counter's first wrap in the run (the plan's, shared by the lanes)."""
    alpha[0] = 0
    beta[0] = min(max(st[COUNT] - pwm, 0), min(first_wrap, n)) if st[PINS] else 0
    k = 1
    wrap = first_wrap
    while wrap < n:  # not range(first_wrap, n, step): its length would cost a division every period
        alpha[k], beta[k] = wrap, min(wrap + st[AMOUNT], n)
        k += 1
        wrap += fw[PWM_PERIOD]
    return k


@inline
def _latch(st, first_wrap, last, n):
    """``HotendLanes.skip``'s soft PWM: counts latched at each wrap, the pin after the last tick (the
    counter's phase ``last`` there)."""
    if first_wrap < n:
        st[COUNT] = st[AMOUNT]
        st[PINS] = 1 if last < st[AMOUNT] else 0
    elif last >= st[COUNT]:
        st[PINS] = 0
    if st[HALTED]:
        st[PINS] = 0


@inline
def _ring_push(st, ring, start, end):
    """Append a pulse [start, end) (absolute ticks) to the lane's ring, merged with one it continues."""
    if end <= start:
        return
    cap = ring.shape[0]
    if st[RING_LEN]:
        last = (st[RING_HEAD] + st[RING_LEN] - 1) % cap
        if ring[last, 1] == start:
            ring[last, 1] = end
            return
    slot = (st[RING_HEAD] + st[RING_LEN]) % cap
    ring[slot, 0], ring[slot, 1] = start, end
    st[RING_LEN] += 1


@inline
def _ring_delayed(st, ring, tick, n, delay, alpha, beta):
    """The pulses the plant sees over ticks [tick, tick + n): the ring's, ``delay`` ticks late,
    relative to ``tick`` and cut to the run; pulses that ended before the run leave the ring."""
    cap = ring.shape[0]
    while st[RING_LEN] and ring[st[RING_HEAD], 1] + delay <= tick:
        st[RING_HEAD] = (st[RING_HEAD] + 1) % cap
        st[RING_LEN] -= 1
    k = 0
    for i in range(st[RING_LEN]):
        slot = (st[RING_HEAD] + i) % cap
        start = ring[slot, 0] + delay - tick
        if start >= n:
            break
        alpha[k], beta[k] = max(start, 0), min(ring[slot, 1] + delay - tick, n)
        k += 1
    return k


@inline
def _ring_cut_last(st, ring):
    """The main loop switched the pin off for the period's last tick: the last pulse ends a tick early."""
    cap = ring.shape[0]
    last = (st[RING_HEAD] + st[RING_LEN] - 1) % cap
    ring[last, 1] -= 1
    if ring[last, 1] <= ring[last, 0]:
        st[RING_LEN] -= 1


@inline
def adc_count(y, count, edges, adc_max):
    """The ADC count of temperature y: how many edges lie above it, walked from a nearby count."""
    while count < adc_max and y < edges[count + 1]:
        count += 1
    while y >= edges[count]:
        count -= 1
    return count


@inline
def _noisy_count(y, count, noise, edges, slopes, bounds, sensor_p, adc_max):
    """floor(analog(y) + noise) clipped to the ADC's range, ``count`` being floor(analog(y))."""
    v = count + (edges[count] - y) * slopes[count] + noise
    m = np.floor(v)
    if v - m <= bounds[count] or m + 1.0 - v <= bounds[count]:  # too near an integer for the line
        r = np.exp((1.0 / (y + sensor_p[SP_KELVIN]) - sensor_p[SP_C1]) / sensor_p[SP_C2])
        m = np.floor(sensor_p[SP_COUNTS] * r / (r + sensor_p[SP_PULLUP]) + noise)
    return int(min(max(m, 0.0), adc_max))


@inline
def _samples(xl, px, pdd, rows, m, kind, s0, n_samples, n_pulses, alpha, beta, ys):
    """Every sample's sensor temperature into ys: loops over the samples innermost (vectorisable), each
    sample's sum in the numpy path's order; a pulse's sensor step at every sample is one row of ``rows``."""
    for j in range(n_samples):
        ys[j] = px[m, kind, 0, j] * xl[0]
    for i in range(1, xl.shape[0]):
        for j in range(n_samples):
            ys[j] = ys[j] + px[m, kind, i, j] * xl[i]
    for j in range(n_samples):
        ys[j] = ys[j] + pdd[m, kind, j]
    for p in range(n_pulses):
        if beta[p] > alpha[p]:
            ra, rb = s0 - alpha[p] + ROW_OFFSET, s0 - beta[p] + ROW_OFFSET
            for j in range(n_samples):
                ys[j] = ys[j] + (rows[m, ra, j] - rows[m, rb, j])


@inline
def _sample(xl, px, pdd, rows, m, kind, s0, j, n_pulses, alpha, beta):
    """Sample j's sensor temperature alone, in ``_samples``' order of operations (the same bits)."""
    y = px[m, kind, 0, j] * xl[0]
    for i in range(1, xl.shape[0]):
        y = y + px[m, kind, i, j] * xl[i]
    y = y + pdd[m, kind, j]
    for p in range(n_pulses):
        if beta[p] > alpha[p]:
            y = y + (rows[m, s0 - alpha[p] + ROW_OFFSET, j] - rows[m, s0 - beta[p] + ROW_OFFSET, j])
    return y


@inline
def _chord(st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind, s0, n_pulses, alpha, beta, edges,
           adc_max, n_samples):
    """``_chord_states`` with the loops over the states unrolled for the common plant."""
    if xl.shape[0] == UNROLLED_STATES:
        return _chord_states(UNROLLED_STATES, st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind,
                             s0, n_pulses, alpha, beta, edges, adc_max, n_samples)
    return _chord_states(xl.shape[0], st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind, s0,
                         n_pulses, alpha, beta, edges, adc_max, n_samples)


@inline
def _chord_states(n_x, st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind, s0, n_pulses, alpha,
                  beta, edges, adc_max, n_samples):
    """(the count at the band's hot end, at its cold end, the first sample, the last, the band): the chord
    through a full period's first and last samples, widened by the band the maps let a sample stray
    from it (``Tables.chords``), holds every sample."""
    last = n_samples - 1  # the two samples and the band: independent sums (in any order: the band's margin
    y0, y1 = pdd[m, kind, 0], pdd[m, kind, last]  # covers the rounding)
    band = CHORD_MARGIN_C + chord_d[m, kind] + chord_sum[m, kind] * abs(xl[0])
    for i in range(n_x):
        y0 += px[m, kind, i, 0] * xl[i]
        y1 += px[m, kind, i, last] * xl[i]
        band += chord_x[m, kind, i] * abs(xl[i] - xl[0])
    for p in range(n_pulses):
        if beta[p] > alpha[p]:
            ra, rb = s0 - alpha[p] + ROW_OFFSET, s0 - beta[p] + ROW_OFFSET
            y0 += rows[m, ra, 0] - rows[m, rb, 0]
            y1 += rows[m, ra, last] - rows[m, rb, last]
            band += chord_rows[m, ra] + chord_rows[m, rb]
    hot = adc_count(max(y0, y1) + band, st[HINT], edges, adc_max)
    return hot, adc_count(min(y0, y1) - band, hot, edges, adc_max), y0, y1, band


@inline
def _chord_counts(hot, cold, y0, step, band, edge, n_samples, xl, px, pdd, rows, m, kind, s0, n_pulses, alpha, beta):
    """``_chord_sum`` without noise: the samples the chord decides counted without a branch (a loop the
    compiler vectorises), then the few it cannot decide computed each."""
    n_cold = n_hot = 0
    for j in range(n_samples):
        yc = y0 + step * j
        n_cold += yc + band < edge
        n_hot += yc - band >= edge
    total = cold * n_cold + hot * n_hot
    if n_cold + n_hot < n_samples:
        for j in range(n_samples):
            yc = y0 + step * j
            if not (yc + band < edge or yc - band >= edge):
                y = _sample(xl, px, pdd, rows, m, kind, s0, j, n_pulses, alpha, beta)
                total += cold if y < edge else hot
    return total


@inline
def _chord_sum(hot, cold, y0, y1, band, n_samples, xl, px, pdd, rows, m, kind, s0, n_pulses, alpha, beta, edges,
               noise_lsb, z, z0, slopes, bounds, sensor_p, adc_max):
    """The counts of a full period whose samples span at most one switching temperature (``cold`` is
    ``hot`` or ``hot + 1``): each sample's count read off the chord, its noisy count off the line through
    its count's edges (within the line's bound plus the band's worth); a sample is computed only when
    the chord cannot tell (near the edge, or a noisy value that near an integer)."""
    if cold == hot and noise_lsb == 0.0:
        return hot * n_samples
    edge = edges[cold]  # below it a sample reads ``cold`` (the same count when cold == hot)
    step = (y1 - y0) / (n_samples - 1)
    if noise_lsb == 0.0:
        return _chord_counts(hot, cold, y0, step, band, edge, n_samples, xl, px, pdd, rows, m, kind, s0, n_pulses,
                             alpha, beta)
    total = 0
    for j in range(n_samples):
        yc = y0 + step * j
        y = yc
        count = cold if yc + band < edge else hot if yc - band >= edge else -1
        if count < 0:  # the chord cannot tell: this sample itself
            y = _sample(xl, px, pdd, rows, m, kind, s0, j, n_pulses, alpha, beta)
            count = cold if y < edge else hot
        noise = noise_lsb * z[z0 + j]
        width = bounds[count] + (band if y == yc else 0.0) * slopes[count]
        v = count + (edges[count] - y) * slopes[count] + noise
        whole = np.floor(v)
        if v - whole > width and whole + 1.0 - v > width:
            total += int(min(max(whole, 0.0), adc_max))
        else:
            if y == yc:
                y = _sample(xl, px, pdd, rows, m, kind, s0, j, n_pulses, alpha, beta)
            total += _noisy_count(y, count, noise, edges, slopes, bounds, sensor_p, adc_max)
    return total


@inline
def _sample_sum(st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind, s0, n, n_pulses, alpha,
                beta, edges, fw, ys, noise_lsb, z, z0, slopes, bounds, sensor_p):
    """The ADC counts of the sensor node at ticks s0, s0 + 10, ... < n, summed (a noisy lane's each
    with its noise)."""
    adc_max = fw[ADC_MAX]
    n_samples = (n - s0 + MIN_ADC_ISR_LOOPS - 1) // MIN_ADC_ISR_LOOPS if n > s0 else 0  # a constant divisor
    if n_samples == 0:
        return 0
    if n_samples == ys.shape[0]:
        hot, cold, y0, y1, band = _chord(st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind, s0,
                                         n_pulses, alpha, beta, edges, adc_max, n_samples)
        if cold - hot <= 1:
            st[HINT] = hot
            return _chord_sum(hot, cold, y0, y1, band, n_samples, xl, px, pdd, rows, m, kind, s0, n_pulses, alpha,
                              beta, edges, noise_lsb, z, z0, slopes, bounds, sensor_p, adc_max)
    _samples(xl, px, pdd, rows, m, kind, s0, n_samples, n_pulses, alpha, beta, ys)
    count = st[HINT]
    total = 0
    for j in range(n_samples):
        count = adc_count(ys[j], count, edges, adc_max)
        if noise_lsb != 0.0:
            total += _noisy_count(ys[j], count, noise_lsb * z[z0 + j], edges, slopes, bounds, sensor_p, adc_max)
        else:
            total += count
    st[HINT] = count
    return total


@inline
def _advance(xl, xn, fx, fdd, steps, m, kind, n, n_pulses, alpha, beta):
    """The state after n ticks: free response, ambient, then each pulse's step response."""
    if xl.shape[0] == UNROLLED_STATES:
        _advance_states(UNROLLED_STATES, xl, xn, fx, fdd, steps, m, kind, n, n_pulses, alpha, beta)
    else:
        _advance_states(xl.shape[0], xl, xn, fx, fdd, steps, m, kind, n, n_pulses, alpha, beta)


@inline
def _advance_states(n_x, xl, xn, fx, fdd, steps, m, kind, n, n_pulses, alpha, beta):
    """``_advance`` on n_x states (a constant where the caller names it: the loops unrolled)."""
    for i in range(n_x):
        v = fx[m, kind, i, 0] * xl[0]
        for k in range(1, n_x):
            v = v + fx[m, kind, i, k] * xl[k]
        v = v + fdd[m, kind, i]
        for p in range(n_pulses):
            if beta[p] > alpha[p]:  # (an empty pulse adds 0.0: skipped, as _samples skips it)
                v = v + (steps[m, n - alpha[p], i] - steps[m, n - beta[p], i])
        xn[i] = v


@inline
def output(io, row, x):
    """io[row, :n_x] . x + io[row, n_x], summed in index order."""
    y = io[row, 0] * x[0]
    for i in range(1, x.shape[0]):
        y = y + io[row, i] * x[i]
    return y + io[row, x.shape[0]]


@inline
def score_row(si, sf, sp, row, flags, temp_c, duty):
    """One reading into the heater objective's accumulators (tools/tuning/objectives.py heater_terms)."""
    error = sp[S_TARGET] - temp_c
    abs_error = abs(error)
    heat = flags & HEAT
    if si[HOLDING] == 0:
        if heat and abs_error <= sp[S_BAND]:
            si[HOLDING], si[REACHED], si[FIRST_ROW] = 1, 1, row
        elif flags & LAST_HEAT:
            si[HOLDING], si[FIRST_ROW] = 1, row
    if heat:
        sf[MAX_BEYOND] = max(sf[MAX_BEYOND], -sp[S_SIGN] * error)
    if si[HOLDING]:
        sf[ABS_ERROR_SUM] += abs_error
        if si[HOLD_ROWS]:
            sf[DUTY_STEP_SUM] += abs(duty - sf[PREV_DUTY])
        si[HOLD_ROWS] += 1
    sf[PREV_DUTY] = duty


@inline
def _plant_pulses(st, plan, q, fw, pulses, ring):
    """The soft PWM's pulses this period into pulses[0]; the ones the plant sees into pulses[1] when it
    has a dead time (the ring's, ``delay`` ticks late). Returns (the PWM's count, the plant's count)."""
    n, pwm = plan[q, N_TICKS], plan[q, PWM_COUNT]
    n_pulses = _pulses(st, pwm, plan[q, FIRST_WRAP], n, fw, pulses[0, 0], pulses[0, 1])
    if not fw[DELAY]:
        return n_pulses, n_pulses
    for p in range(n_pulses):
        _ring_push(st, ring, plan[q, TICK] + pulses[0, 0, p], plan[q, TICK] + pulses[0, 1, p])
    return n_pulses, _ring_delayed(st, ring, plan[q, TICK], n, fw[DELAY], pulses[1, 0], pulses[1, 1])


@inline
def _plant_bin(xl, io, fw, n_bins):
    """The model a radiating lane runs this period: its block's bin from BIN_LO (0 when linear);
    n_bins when the tables lack it."""
    if not fw[RADIATING]:
        return 0
    m = int(np.rint(output(io[0], 1, xl) * 2.0)) - fw[BIN_LO]
    return m if 0 <= m < n_bins else n_bins


@inline
def _reading(st, si, sf, score_p, fw, plan, q, io, m, xl, lane, rec_temp, rec_amount, rec_block, rec_sensor):
    """A reading's record and its heater-objective accumulation."""
    r = plan[q, ROW]
    if fw[RECORD]:
        rec_temp[lane, r], rec_amount[lane, r] = st[TEMP], st[AMOUNT]
        rec_block[lane, r] = output(io[m], 1, xl)
        rec_sensor[lane, r] = output(io[m], 2, xl)
    if fw[SCORE] and plan[q, FLAGS] & SCORED:
        score_row(si, sf, score_p, fw[ROW_BASE] + r, plan[q, FLAGS], st[TEMP] / (1 << fw[TEMP_FRAC_BITS]),
                  float(st[AMOUNT]))


@jit
def run_lanes(todo, lane_ids, q_start, plan, px, pdd, fx, fdd, rows, chord_x, chord_sum, chord_d, chord_rows, steps, io,
              edges, slopes, bounds, sensor_p, lut, fw, cparams, rules, istate, x, noise_lsb, streams, z, ring, score_i,
              score_f, score_p, rec_temp, rec_amount, rec_block, rec_sensor, pulses, x_pair, ys, strengths, stop,
              need_bin):
    """Every period of ``plan`` from ``q_start[k]`` on each lane k of ``todo`` (its column of ``x``;
    ``lane_ids[k]`` its row of the per-lane arrays); ``stop[k]``: where it stopped (len(plan) when done,
    else the period whose block bin ``need_bin[k]`` the tables lack, or, probing, the first tuned
    reading's, ``need_bin[k]`` then ``PROBED``).

    plan (P, PLAN_COLUMNS) int64 (see the columns above). Tables by model m (the radiating bin from
    ``fw[BIN_LO]``; one model when linear) and period kind: px (M, kinds, n_x, samples) and pdd the
    sensor's free response at each sample, fx and fdd the state's; rows (M, ROW_OFFSET + 10, samples)
    the heater's sensor step at each sample; chord_* how far samples stray from their chord
    (``Tables.chords``); steps (M, 161, n_x) the state's step response; io (M, 3, n_x + 1): the
    heater's one-tick response, then the block and sensor outputs with their constants. Noise: lane's
    ``noise_lsb`` times ``z[streams[lane], Z_FIRST + j]``. ring (N, cap, 2): past pulses (dead time
    ``fw[DELAY]`` ticks). Scratch: pulses (2, 2, MAX_PULSES) int64, x_pair (2, n_x) and ys float64,
    strengths (7,) int64.
    """
    xl, xn = x_pair[0], x_pair[1]
    n_bins = px.shape[0]
    seen = 1 if fw[DELAY] else 0  # which pulses the plant sees: the PWM's, or the ring's
    for k in todo:
        lane = lane_ids[k]
        st, cp = istate[lane], cparams[lane]
        for i in range(xl.shape[0]):
            xl[i] = x[i, k]
        q = q_start[k]
        while q < plan.shape[0]:
            m = _plant_bin(xl, io, fw, n_bins)
            if m == n_bins:  # the block left the tables: BatchTwin builds more bins
                need_bin[k] = int(np.rint(output(io[0], 1, xl) * 2.0))
                break
            n, s0 = plan[q, N_TICKS], plan[q, FIRST_SAMPLE]
            n_pulses, n_seen = _plant_pulses(st, plan, q, fw, pulses, ring[lane])
            a, b = pulses[seen, 0], pulses[seen, 1]
            st[ACC] += _sample_sum(st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, plan[q, KIND],
                                   s0, n, n_seen, a, b, edges, fw, ys, noise_lsb[lane], z[streams[lane]],
                                   plan[q, Z_FIRST], slopes, bounds, sensor_p)
            _latch(st, plan[q, FIRST_WRAP], plan[q, LAST_PHASE], n)
            pins_before = st[PINS]
            if plan[q, READING]:
                raw, st[ACC] = st[ACC], 0
                if _task(st, raw, plan[q, MILLIS], lut, cp, fw, rules, strengths):
                    need_bin[k] = PROBED  # its state is left mid-period
                    break
            _advance(xl, xn, fx, fdd, steps, m, plan[q, KIND], n, n_seen, a, b)
            if fw[DELAY] and pins_before and not st[PINS]:
                _ring_cut_last(st, ring[lane])  # the main loop switched the pin off for the last tick
            diff = 0.0 if fw[DELAY] else float(st[PINS] - pins_before)  # (without dead time: now)
            for i in range(xl.shape[0]):
                xl[i] = xn[i] + io[m, 0, i] * diff
            if plan[q, READING]:
                _reading(st, score_i[lane], score_f[lane], score_p, fw, plan, q, io, m, xl, lane, rec_temp, rec_amount,
                         rec_block, rec_sensor)
            q += 1
        stop[k] = q
        for i in range(xl.shape[0]):
            x[i, k] = xl[i]
