"""The batch twin's control periods as one compiled loop per lane (numba), for speed.

``BatchTwin`` runs N hotend twins as numpy lanes (``firmware_port.marlin.lanes``): every control
period costs some fifty numpy calls on N-element arrays, so the interpreter, not the
arithmetic, sets the pace. Here the same period (soft-PWM pulses, the sensor samples through the
plant's exact tick maps, the ADC sums, ``updateTemperaturesFromRawValues`` and
``manage_hotends``: protection and the fixed-point PID) runs lane by lane over a whole stretch
between scenario events, each lane's state in one cache line or two.

Same results as the numpy lanes, bit for bit: the firmware is integer arithmetic (``//`` and
``>>`` floor in numba as in numpy); the plant's float arithmetic is written in the same order
of operations here as in ``BatchTwin``'s numpy period, without fused multiply-adds (numba does
not contract without fastmath), and the ADC uses the same table of switching temperatures
(``twin.adc_table``). tests/test_lanes.py runs both and compares every record and state.

``HEATER_TWIN_KERNEL`` picks the implementation: ``numba`` (default when numba is installed,
``pip install heater-twin[fast]``) or ``numpy``. Without numba, ``BatchTwin(kernel="numba")``
still runs the loop below as plain Python: slow, but the tests check the same code that way.
"""

from __future__ import annotations

import os

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

try:
    import numba
except ImportError:  # the optional `fast` extra
    numba = None  # type: ignore[assignment]

KERNELS = ("numba", "numpy")
KERNEL_ENV = "HEATER_TWIN_KERNEL"

# Per-lane integer state, the columns of ``istate`` (N, N_STATE).
(AMOUNT, COUNT, PINS, TEMP, HALTED, TRIP, R_STATE, R_TIMER, W_TARGET, W_NEXT, I_SUM, D_TERM, PREV,
 RESET, ACC, HINT) = range(16)
N_STATE = 16
# Per-lane gains, the columns of ``gains`` (N, 4), as PidFixed scales them.
KP, KI, KD, I_MAX = range(4)
# Firmware constants, the entries of ``fw``: passed in, not frozen into the cached machine code.
(TARGET, RUNAWAY_RESET, RAW_MAX, RAW_MIN, MINTEMP_Q5, MAXTEMP_Q5, R_PERIOD_MS, R_HYST_C, W_INC_C,
 W_HYST_C, W_PERIOD_MS, EVERY_SAMPLE, P_SHIFT, I_SHIFT, D_SHIFT, D_LIMIT_Q8, D_DIVISOR, RANGE_Q5,
 OUT_MAX_Q8, OUT_FRAC_BITS, TEMP_FRAC_BITS, PWM_PERIOD, ADC_MAX, SAMPLE_EVERY) = range(24)
N_FW = 24
MAX_PULSES = 3  # a run of <= 160 ticks holds the tail of a pulse and at most two 127-tick wraps


def default_kernel() -> str:
    """The kernel ``HEATER_TWIN_KERNEL`` names, else numba when installed; ValueError names a bad value."""
    kernel = os.environ.get(KERNEL_ENV, "numba" if numba is not None else "numpy")
    if kernel not in KERNELS:
        raise ValueError(f"{KERNEL_ENV}={kernel!r}: must be one of {', '.join(KERNELS)}")
    if kernel == "numba" and numba is None:
        raise ValueError(f"{KERNEL_ENV}=numba: numba is not installed (pip install 'heater-twin[fast]')")
    return kernel


def describe() -> str:
    return f"numba {numba.__version__}" if numba is not None else "numba not installed"


# The loop allocates nothing (its scratch arrays come in), so it runs without numba's reference
# counting: passing arrays to the inlined helpers would otherwise cost an atomic increment and
# decrement each, per period, more than the arithmetic (0.96 s against 0.39 s of CPU for 1000
# lanes x 600 s on the 2-core reference machine). ``_nrt`` is numba's own switch for that runtime
# (underscored, so not promised: tests/test_lanes.py, run against numba in CI, would catch a change).
NUMBA_OPTIONS = {"_nrt": False}


def _jit(fn):
    return numba.njit(cache=True, **NUMBA_OPTIONS)(fn) if numba is not None else fn


def _inline(fn):
    """A helper of ``run_lanes``, inlined into it."""
    return numba.njit(inline="always", **NUMBA_OPTIONS)(fn) if numba is not None else fn


@_inline
def _shr_round(x, n):
    return (x + (1 << (n - 1))) >> n


@_inline
def _div_round(a, b):
    half = b // 2
    return (a + half) // b if a >= 0 else -((-a + half) // b)


@_inline
def _trip(st, code):
    """_temp_error: heater off, board halted (once)."""
    if st[HALTED] == 0:
        st[TRIP], st[HALTED], st[AMOUNT], st[COUNT], st[PINS] = code, 1, 0, 0, 0


@_inline
def _pid_band(st, temp, e, g, fw):
    """The PID law inside the functional range; state kept in ``st``."""
    i_sum, d_term = (0, 0) if st[RESET] else (st[I_SUM], st[D_TERM])
    i_sum = min(max(i_sum + e, 0), g[I_MAX])
    p = _shr_round(g[KP] * e, fw[P_SHIFT])
    i = _shr_round(g[KI] * i_sum, fw[I_SHIFT])
    d_in = min(max(_shr_round(g[KD] * (st[PREV] - temp), fw[D_SHIFT]), -fw[D_LIMIT_Q8]), fw[D_LIMIT_Q8])
    d_term = d_term + _div_round(d_in - d_term, fw[D_DIVISOR])
    st[I_SUM], st[D_TERM], st[PREV], st[RESET] = i_sum, d_term, temp, 0
    return min(max(p + i + d_term, 0), fw[OUT_MAX_Q8])


@_inline
def _pid(st, temp, target, g, fw):
    """``PidLanes.update_q8`` on one active lane: Q.8 output."""
    e = (target << fw[TEMP_FRAC_BITS]) - temp
    if -fw[RANGE_Q5] <= e <= fw[RANGE_Q5] and target != 0:
        return _pid_band(st, temp, e, g, fw)
    st[RESET] = 1
    if fw[EVERY_SAMPLE]:
        st[PREV] = temp
    return fw[OUT_MAX_Q8] if target != 0 and e > fw[RANGE_Q5] else 0


@_inline
def _runaway(st, temp, target, now, reset, fw):
    """``RunawayMonitor.run``; ``reset``: the target changed since the last reading."""
    if reset and st[HALTED] == 0:
        st[R_STATE] = FIRST_HEATING if target > 0 else INACTIVE
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


@_inline
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


@_inline
def _task(st, raw, now, reset, lut, g, fw):
    """``HotendLanes.task`` on one lane with a fresh reading."""
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
    _runaway(st, temp, target, now, reset, fw)
    in_range = st[HALTED] == 0 and fw[MINTEMP_Q5] < temp < fw[MAXTEMP_Q5]
    out_q8 = _pid(st, temp, target, g, fw) if in_range else 0
    st[AMOUNT] = (out_q8 >> fw[OUT_FRAC_BITS]) >> 1 if in_range else 0
    _watch(st, temp, target, now, fw)


@_inline
def _pulses(st, pwm, n, fw, alpha, beta):
    """``HotendLanes.pulses``: the heater is on over ticks [alpha, beta); returns how many pulses."""
    first_wrap = (fw[PWM_PERIOD] - pwm) % fw[PWM_PERIOD]
    alpha[0] = 0
    beta[0] = min(max(st[COUNT] - pwm, 0), min(first_wrap, n)) if st[PINS] else 0
    k = 1
    for wrap in range(first_wrap, n, fw[PWM_PERIOD]):
        alpha[k], beta[k] = wrap, min(wrap + st[AMOUNT], n)
        k += 1
    return k


@_inline
def _latch(st, pwm, n, fw):
    """``HotendLanes.skip``'s soft PWM: counts latched at each wrap, the pin after the last tick."""
    first_wrap = (fw[PWM_PERIOD] - pwm) % fw[PWM_PERIOD]
    last = (pwm + n - 1) % fw[PWM_PERIOD]
    if first_wrap < n:
        st[COUNT] = st[AMOUNT]
        st[PINS] = 1 if last < st[AMOUNT] else 0
    elif last >= st[COUNT]:
        st[PINS] = 0
    if st[HALTED]:
        st[PINS] = 0


@_inline
def _sample_sum(st, x, px, pdd, kind, s0, n, n_pulses, alpha, beta, sstep, edges, fw, ys):
    """The ADC counts of the sensor node at ticks s0, s0 + 10, ... < n, summed.

    Loops over the samples innermost (vectorisable), each sample's sum in the numpy path's order.
    """
    step = fw[SAMPLE_EVERY]
    n_samples = (n - s0 + step - 1) // step if n > s0 else 0
    for j in range(n_samples):
        ys[j] = px[kind, 0, j] * x[0]
    for i in range(1, x.shape[0]):
        for j in range(n_samples):
            ys[j] = ys[j] + px[kind, i, j] * x[i]
    for j in range(n_samples):
        ys[j] = ys[j] + pdd[kind, j]
    for p in range(n_pulses):
        for j in range(n_samples):
            s = s0 + step * j
            ys[j] = ys[j] + (sstep[max(s - alpha[p], 0)] - sstep[max(s - beta[p], 0)])
    total, count = 0, st[HINT]
    for j in range(n_samples):
        while count < fw[ADC_MAX] and ys[j] < edges[count + 1]:
            count += 1
        while ys[j] >= edges[count]:
            count -= 1
        total += count
    st[HINT] = count
    return total


@_inline
def _advance(x, out, fx, fdd, kind, n, n_pulses, alpha, beta, steps):
    """The state after n ticks: free response, ambient, then each pulse's step response."""
    for i in range(x.shape[0]):
        v = fx[kind, i, 0] * x[0]
        for k in range(1, x.shape[0]):
            v = v + fx[kind, i, k] * x[k]
        v = v + fdd[kind, i]
        for p in range(n_pulses):
            v = v + (steps[n - alpha[p], i] - steps[n - beta[p], i])
        out[i] = v


@_jit
def run_lanes(plan, kind_px, kind_pdd, kind_fx, kind_fdd, sstep, steps, plant_io, edges, lut, fw, gains,
              istate, x, rec_temp, rec_amount, rec_block, rec_sensor, pulses, x_pair, ys):
    """Every period of ``plan`` on every lane; one record column per reading period.

    plan (P, 6) int64: n ticks, first sample offset, reading 0/1, soft-PWM count at the start,
    millis() at the end, kind. kind_* index the maps by kind. plant_io (3, n_x + 1): the heater
    input's one-tick response g, then the block and sensor output rows with their constant.
    Scratch: pulses (2, MAX_PULSES) int64, x_pair (2, n_x) and ys (samples per period) float64.
    kind_px is (kinds, n_x, samples): contiguous along the samples.
    """
    n_x = x.shape[0]
    alpha, beta, xl, xn = pulses[0], pulses[1], x_pair[0], x_pair[1]
    for lane in range(x.shape[1]):
        st, g = istate[lane], gains[lane]
        for i in range(n_x):
            xl[i] = x[i, lane]
        r, reset = 0, fw[RUNAWAY_RESET]
        for q in range(plan.shape[0]):
            n, s0, reading, pwm, now, kind = plan[q, 0], plan[q, 1], plan[q, 2], plan[q, 3], plan[q, 4], plan[q, 5]
            n_pulses = _pulses(st, pwm, n, fw, alpha, beta)
            st[ACC] += _sample_sum(st, xl, kind_px, kind_pdd, kind, s0, n, n_pulses, alpha, beta, sstep,
                                   edges, fw, ys)
            _latch(st, pwm, n, fw)
            pins_before = st[PINS]
            if reading:
                raw, st[ACC] = st[ACC], 0
                _task(st, raw, now, reset, lut, g, fw)
                reset = 0
            _advance(xl, xn, kind_fx, kind_fdd, kind, n, n_pulses, alpha, beta, steps)
            diff = float(st[PINS] - pins_before)
            for i in range(n_x):
                xl[i] = xn[i] + plant_io[0, i] * diff
            if reading:
                rec_temp[lane, r], rec_amount[lane, r] = st[TEMP], st[AMOUNT]
                rec_block[lane, r] = _output(plant_io, 1, xl)
                rec_sensor[lane, r] = _output(plant_io, 2, xl)
                r += 1
        for i in range(n_x):
            x[i, lane] = xl[i]


@_inline
def _output(io, row, x):
    """io[row, :n_x] . x + io[row, n_x], summed in index order."""
    y = io[row, 0] * x[0]
    for i in range(1, x.shape[0]):
        y = y + io[row, i] * x[i]
    return y + io[row, x.shape[0]]
