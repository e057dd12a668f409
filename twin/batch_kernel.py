"""The batch twin's control periods as one compiled loop per lane (numba), for speed.

``BatchTwin`` runs N hotend twins as numpy lanes (``firmware_port.marlin.lanes``): every control
period costs some fifty numpy calls on N-element arrays, so the interpreter, not the
arithmetic, sets the pace. Here the same period (soft-PWM pulses, the sensor samples through the
plant's exact tick maps, the ADC sums, ``updateTemperaturesFromRawValues`` and
``manage_hotends``: protection and the controller) runs lane by lane over a whole stretch
between scenario events, each lane's state in one cache line or two. What a lane can run:

- controllers: any family that declares a lane law beside its scalar class
  (firmware_port/lane_law.py: Marlin's PID, bang-bang and MPC, seed 004's fuzzy PI, seed 001's
  fuzzy-PID, a user's own): the law's step is compiled into this loop, one compiled loop per law
  (``law_kernel``), one family per batch, parameters and state per lane as the law's records.
  This module holds the board and the plant, no family's maths;
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

``HEATER_TWIN_KERNEL`` picks the implementation (``BatchTwin(kernel=...)`` the same per batch):

- ``numba`` (the default where numba compiles: a core dependency where PyPI has its wheels, else
  ``pip install heater-twin[fast]``): this loop, compiled, for every batch;
- ``numpy`` (the default without numba, or with ``NUMBA_DISABLE_JIT=1``): the numpy lanes where
  they run (linear plants, with a dead time too (twin/lane_ring.py), and laws that do not read the
  board: tens of times the compiled loop's CPU), this loop elsewhere (a radiating loss, Marlin's
  MPC), as plain Python without numba, about a thousand times: the same answers either way
  (docs/performance.md, ``python -m tools.bench fallback``).

Without numba (or with ``NUMBA_DISABLE_JIT=1``, when numba's decorators return the Python
functions) ``kernel="numba"`` still runs this loop as plain Python: slow, but the tests check the
same code that way (tests/twin/test_fallback.py). The loop releases the GIL, so ``BatchTwin``
spreads lanes over threads.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from firmware_port.lane_law import LaneLaw
from firmware_port.law_jit import NUMBA_OPTIONS, jitable, source_hash
from firmware_port.marlin.constants import MIN_ADC_ISR_LOOPS, TICKS_PER_READING  # frozen in: constant divisors
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
from firmware_port.thermistor import TEMP_FRAC_BITS
from twin.numba_cache import cached_njit, law_cache_folder
from twin.streaming import HEAT, LAST_HEAT, SCORED  # frozen in: the objective's row flags

try:
    import numba
except ImportError:  # the optional `fast` extra
    numba = None  # type: ignore[assignment]

KERNELS = ("numba", "numpy")
KERNEL_ENV = "HEATER_TWIN_KERNEL"


def _int64_record(names: str) -> np.dtype:
    return np.dtype([(name, np.int64) for name in names.split()])


# A lane's board (``Lanes.board``): soft PWM (amount, count, pins), the last reading, protection, the ADC's
# running sum and a search start for the next count (hint), the dead-time ring's head and length.
# runaway_pending: the target changed since the lane's last reading (the runaway monitor restarts).
BOARD = _int64_record("amount count pins temp_q5 halted trip runaway_state runaway_timer_ms watch_target_c "
                      "watch_next_ms acc hint runaway_pending ring_head ring_len")
# The board's constants and this call's settings (one record, ``fw``): passed in, not frozen into the
# cached machine code. probe: stop a lane at its first reading whose control reads its tuning (``tuned``).
FIRMWARE = _int64_record("target_c raw_max raw_min mintemp_q5 maxtemp_q5 runaway_period_ms runaway_hysteresis_c "
                         "watch_increase_c watch_hysteresis_c watch_period_ms pwm_period adc_max delay bin_lo "
                         "radiating record score row_base probe fan_speed")
# The plan of a stretch, one record per period: its ticks, its first sample's offset, whether it ends
# in a reading, the soft-PWM counter at its start, millis() at its end, its kind (tables' index), its
# first tick, its reading's row, the row's objective flags, its first noise draw, the soft-PWM
# counter's first wrap and its phase at the last tick, the E stepper at the reading (``BoardInputs``).
PLAN = _int64_record("n_ticks first_sample reading pwm_count millis kind tick row score_flags z_first first_wrap "
                     "last_phase e_position_steps")
PROBED = -(1 << 62)  # ``need_bin`` of a lane the probe stopped (not a bin: no block is that cold)
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


class Work(NamedTuple):
    """Which lanes a call runs (``todo``: their places in the group, ``lane_ids``: their lane numbers), from
    where (``q_start``), and where each stopped (``stop``, ``need_bin``), per place."""

    todo: np.ndarray
    lane_ids: np.ndarray
    q_start: np.ndarray
    stop: np.ndarray
    need_bin: np.ndarray


class PlantMaps(NamedTuple):
    """A group's plant tables by model m and period kind (twin/lane_tables.py ``Tables``): px (M, kinds,
    n_x, samples) and pdd the sensor's free response at each sample, fx and fdd the state's; rows
    (M, ROW_OFFSET + 10, samples) the heater's sensor step at each sample; chord_* how far samples stray
    from their chord (``Tables.chords``); steps (M, 161, n_x) the state's step response; io (M, 3,
    n_x + 1): the heater's one-tick response, then the block and sensor outputs with their constants."""

    px: np.ndarray
    pdd: np.ndarray
    fx: np.ndarray
    fdd: np.ndarray
    rows: np.ndarray
    chord_x: np.ndarray
    chord_sum: np.ndarray
    chord_d: np.ndarray
    chord_rows: np.ndarray
    steps: np.ndarray
    io: np.ndarray


class AdcMaps(NamedTuple):
    """The ADC: switching temperatures (``twin.adc_table``), the noisy line's slopes and bounds, the
    thermistor's constants (``sensor_p``), and the firmware's temperature of every raw sum (``lut``)."""

    edges: np.ndarray
    slopes: np.ndarray
    bounds: np.ndarray
    sensor_p: np.ndarray
    lut: np.ndarray


class Lanes(NamedTuple):
    """Per lane: the board (``BOARD``), the law's parameters and state (its records), the plant state
    (n_x, group places) and the dead-time ring of past pulses (N, cap, 2)."""

    board: np.ndarray
    params: np.ndarray
    state: np.ndarray
    x: np.ndarray
    ring: np.ndarray


class Noise(NamedTuple):
    """Lane k's noise at sample j of a period: ``noise_lsb[k] * z[streams[k], z_first + j]``."""

    noise_lsb: np.ndarray
    streams: np.ndarray
    z: np.ndarray


class Score(NamedTuple):
    """The heater objective's accumulators per lane (``score_i``, ``score_f``) and its constants."""

    score_i: np.ndarray
    score_f: np.ndarray
    score_p: np.ndarray


class Records(NamedTuple):
    """One column per reading row, one row per lane: the reading, the amount, the block and the sensor."""

    temp: np.ndarray
    amount: np.ndarray
    block: np.ndarray
    sensor: np.ndarray


class Scratch(NamedTuple):
    """A call's working memory: pulses (2, 2, MAX_PULSES) int64, x_pair (2, n_x) and ys (samples,) float64,
    the law's ``BoardInputs`` (1,) record."""

    pulses: np.ndarray
    x_pair: np.ndarray
    ys: np.ndarray
    inputs: np.ndarray


def default_kernel() -> str:
    """The kernel ``HEATER_TWIN_KERNEL`` names, else numba where it compiles; ValueError names a bad value."""
    kernel = os.environ.get(KERNEL_ENV, "numba" if compiled() else "numpy")
    if kernel not in KERNELS:
        raise ValueError(f"{KERNEL_ENV}={kernel!r}: must be one of {', '.join(KERNELS)}")
    if kernel == "numba" and numba is None:
        raise ValueError(f"{KERNEL_ENV}=numba: numba is not installed (pip install 'heater-twin[fast]')")
    return kernel


def compiled() -> bool:
    """Whether the loop below runs as machine code (numba installed, its JIT not disabled)."""
    return numba is not None and not numba.config.DISABLE_JIT  # type: ignore[attr-defined]


def describe() -> str:
    if numba is None:
        return "numba not installed"
    return f"numba {numba.__version__}" + ("" if compiled() else " (NUMBA_DISABLE_JIT: plain Python)")


def jit(fn, folder: Path | None = None):
    """A kernel: compiled, cached (twin/numba_cache.py; in ``folder`` if given), releasing the GIL (BatchTwin
    runs lanes on threads)."""
    return cached_njit(fn, folder, nogil=True, **NUMBA_OPTIONS) if numba is not None else fn


def inline(fn):
    """A helper of a kernel, inlined into it."""
    return numba.njit(inline="always", **NUMBA_OPTIONS)(fn) if numba is not None else fn


@inline
def _trip(st, code):
    """_temp_error: heater off, board halted (once)."""
    if st.halted == 0:
        st.trip, st.halted, st.amount, st.count, st.pins = code, 1, 0, 0, 0


# -- protection and the main loop ---------------------------------------------------------------
@inline
def _runaway(st, temp, target, now, fw):
    """``RunawayMonitor.run``; R_PENDING: the target changed since the lane's last reading."""
    if st.runaway_pending and st.halted == 0:
        st.runaway_state = FIRST_HEATING if target > 0 else INACTIVE
    st.runaway_pending = 0
    state = st.runaway_state
    if state == FIRST_HEATING and temp >= target << TEMP_FRAC_BITS:
        state = STABLE
    if state == STABLE:
        if temp >= (target - fw.runaway_hysteresis_c) << TEMP_FRAC_BITS:
            st.runaway_timer_ms = now + fw.runaway_period_ms
        elif now >= st.runaway_timer_ms:
            state = RUNAWAY
    st.runaway_state = state
    if state == RUNAWAY:
        _trip(st, RUNAWAY_TRIP)


@inline
def _watch(st, temp, target, now, fw):
    """``HeaterWatch.heating_failed``: re-arm from the current temperature if risen enough, else trip."""
    if st.watch_next_ms == 0 or now < st.watch_next_ms:
        return
    whole_c = temp >> TEMP_FRAC_BITS if temp >= 0 else -((-temp) >> TEMP_FRAC_BITS)
    if whole_c < st.watch_target_c:
        _trip(st, WATCH_TRIP)
        return
    cur = whole_c + fw.watch_increase_c
    if target != 0 and cur < target - fw.watch_hysteresis_c - 1:
        st.watch_target_c, st.watch_next_ms = cur, now + fw.watch_period_ms
    else:
        st.watch_next_ms = 0


@inline
def _protect(st, raw, now, lut, fw):
    """``HotendLanes.task`` up to the controller, on one lane with a fresh reading: the temperature, the
    MAXTEMP, MINTEMP and runaway checks; whether the controller runs (the lane alive, in range)."""
    target = fw.target_c
    if st.halted == 0:
        st.temp_q5 = lut[raw]
        if raw < fw.raw_max:
            _trip(st, MAXTEMP_TRIP)
    temp = st.temp_q5
    if target > 0 and raw > fw.raw_min:
        _trip(st, MINTEMP_TRIP)
    if temp > fw.maxtemp_q5:
        _trip(st, MAXTEMP_TRIP)
    _runaway(st, temp, target, now, fw)
    return st.halted == 0 and fw.mintemp_q5 < temp < fw.maxtemp_q5


# -- the soft PWM and the plant -------------------------------------------------------------------
@inline
def _pulses(st, pwm, first_wrap, n, fw, alpha, beta):
    """``HotendLanes.pulses``: the heater is on over ticks [alpha, beta); returns how many pulses.
    ``first_wrap``: the soft-PWM counter's first wrap in the run (the plan's, shared by the lanes)."""
    alpha[0] = 0
    beta[0] = min(max(st.count - pwm, 0), min(first_wrap, n)) if st.pins else 0
    k = 1
    wrap = first_wrap
    while wrap < n:  # not range(first_wrap, n, step): its length would cost a division every period
        alpha[k], beta[k] = wrap, min(wrap + st.amount, n)
        k += 1
        wrap += fw.pwm_period
    return k


@inline
def _latch(st, first_wrap, last, n):
    """``HotendLanes.skip``'s soft PWM: counts latched at each wrap, the pin after the last tick (the
    counter's phase ``last`` there)."""
    if first_wrap < n:
        st.count = st.amount
        st.pins = 1 if last < st.amount else 0
    elif last >= st.count:
        st.pins = 0
    if st.halted:
        st.pins = 0


@inline
def _ring_push(st, ring, start, end):
    """Append a pulse [start, end) (absolute ticks) to the lane's ring, merged with one it continues."""
    if end <= start:
        return
    cap = ring.shape[0]
    if st.ring_len:
        last = (st.ring_head + st.ring_len - 1) % cap
        if ring[last, 1] == start:
            ring[last, 1] = end
            return
    slot = (st.ring_head + st.ring_len) % cap
    ring[slot, 0], ring[slot, 1] = start, end
    st.ring_len += 1


@inline
def _ring_delayed(st, ring, tick, n, delay, alpha, beta):
    """The pulses the plant sees over ticks [tick, tick + n): the ring's, ``delay`` ticks late,
    relative to ``tick`` and cut to the run; pulses that ended before the run leave the ring."""
    cap = ring.shape[0]
    while st.ring_len and ring[st.ring_head, 1] + delay <= tick:
        st.ring_head = (st.ring_head + 1) % cap
        st.ring_len -= 1
    k = 0
    for i in range(st.ring_len):
        slot = (st.ring_head + i) % cap
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
    last = (st.ring_head + st.ring_len - 1) % cap
    ring[last, 1] -= 1
    if ring[last, 1] <= ring[last, 0]:
        st.ring_len -= 1


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
    hot = adc_count(max(y0, y1) + band, st.hint, edges, adc_max)
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
    adc_max = fw.adc_max
    n_samples = (n - s0 + MIN_ADC_ISR_LOOPS - 1) // MIN_ADC_ISR_LOOPS if n > s0 else 0  # a constant divisor
    if n_samples == 0:
        return 0
    if n_samples == ys.shape[0]:
        hot, cold, y0, y1, band = _chord(st, xl, px, pdd, rows, chord_x, chord_sum, chord_d, chord_rows, m, kind, s0,
                                         n_pulses, alpha, beta, edges, adc_max, n_samples)
        if cold - hot <= 1:
            st.hint = hot
            return _chord_sum(hot, cold, y0, y1, band, n_samples, xl, px, pdd, rows, m, kind, s0, n_pulses, alpha,
                              beta, edges, noise_lsb, z, z0, slopes, bounds, sensor_p, adc_max)
    _samples(xl, px, pdd, rows, m, kind, s0, n_samples, n_pulses, alpha, beta, ys)
    count = st.hint
    total = 0
    for j in range(n_samples):
        count = adc_count(ys[j], count, edges, adc_max)
        if noise_lsb != 0.0:
            total += _noisy_count(ys[j], count, noise_lsb * z[z0 + j], edges, slopes, bounds, sensor_p, adc_max)
        else:
            total += count
    st.hint = count
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
def _plant_pulses(st, row, fw, pulses, ring):
    """The soft PWM's pulses this period into pulses[0]; the ones the plant sees into pulses[1] when it
    has a dead time (the ring's, ``delay`` ticks late). Returns (the PWM's count, the plant's count)."""
    n = row.n_ticks
    n_pulses = _pulses(st, row.pwm_count, row.first_wrap, n, fw, pulses[0, 0], pulses[0, 1])
    if not fw.delay:
        return n_pulses, n_pulses
    for p in range(n_pulses):
        _ring_push(st, ring, row.tick + pulses[0, 0, p], row.tick + pulses[0, 1, p])
    return n_pulses, _ring_delayed(st, ring, row.tick, n, fw.delay, pulses[1, 0], pulses[1, 1])


@inline
def _plant_bin(xl, io, fw, n_bins):
    """The model a radiating lane runs this period: its block's bin from ``bin_lo`` (0 when linear);
    n_bins when the tables lack it."""
    if not fw.radiating:
        return 0
    m = int(np.rint(output(io[0], 1, xl) * 2.0)) - fw.bin_lo
    return m if 0 <= m < n_bins else n_bins


@inline
def _board_inputs(inputs, st, fw, row):
    """What a law that reads the board sees at this reading (``BoardInputs``)."""
    inputs.amount, inputs.fan_speed, inputs.e_position_steps = st.amount, fw.fan_speed, row.e_position_steps
    return inputs


@inline
def _end_period(st, ring, xl, xn, g, fw, pins_before):
    """The plant state at the period's end: where the main loop switched the pin for the last tick, the
    heater's one-tick response g (without dead time) or the ring's last pulse (with it) takes that in."""
    if fw.delay and pins_before and not st.pins:
        _ring_cut_last(st, ring)  # the last pulse ends a tick early
    diff = 0.0 if fw.delay else float(st.pins - pins_before)
    for i in range(xl.shape[0]):
        xl[i] = xn[i] + g[i] * diff


@inline
def _reading(st, score, lane, fw, row, io, m, xl, records):
    """A reading's record and its heater-objective accumulation."""
    r = row.row
    if fw.record:
        records.temp[lane, r], records.amount[lane, r] = st.temp_q5, st.amount
        records.block[lane, r] = output(io[m], 1, xl)
        records.sensor[lane, r] = output(io[m], 2, xl)
    if fw.score and row.score_flags & SCORED:
        score_row(score.score_i[lane], score.score_f[lane], score.score_p, fw.row_base + r, row.score_flags,
                  st.temp_q5 / (1 << TEMP_FRAC_BITS), float(st.amount))


def never_tuned(p, s, temp_q5, target_c):
    """A law without ``tuning``: no reading reads parameters beyond those lanes sharing a run agree on."""
    return False


@functools.cache
def law_kernel(law: LaneLaw) -> Callable[..., None]:
    """The batch's loop with ``law``'s step compiled in: one compiled function per law (numba caches
    each on disk, keyed by the law's source, ``law_source``, in the user's cache folder: law_cache_folder)."""
    step, tuned = jitable(law.step), jitable(law.tuned or never_tuned)
    source = law_source(law)

    def run_lanes(work, plan, maps, adc, fw, lanes, noise, score, records, scratch):
        """Every period of ``plan`` from ``work.q_start[k]`` on each lane k of ``work.todo`` (its column of
        ``lanes.x``; ``work.lane_ids[k]`` its row of the per-lane arrays); ``work.stop[k]``: where it
        stopped (len(plan) when done, else the period whose block bin ``work.need_bin[k]`` the tables
        lack, or, probing, the first tuned reading's, ``need_bin[k]`` then ``PROBED``).

        plan: (P,) ``PLAN`` records; maps: ``PlantMaps``; adc: ``AdcMaps``; fw: (1,) ``FIRMWARE``
        record; lanes: ``Lanes`` (the board, the law's parameters and state, the plant states, the
        dead-time rings); noise: lane k's noise is ``noise_lsb[k] * z[streams[k], z_first + j]``.
        """
        if not source:  # never (law_source is odd): a closure variable, so numba's cache key holds the law
            return
        f = fw[0]
        target = f.target_c
        xl, xn = scratch.x_pair[0], scratch.x_pair[1]
        pulses, inputs = scratch.pulses, scratch.inputs[0]
        n_bins = maps.px.shape[0]
        seen = 1 if f.delay else 0  # which pulses the plant sees: the PWM's, or the ring's
        for k in work.todo:
            lane = work.lane_ids[k]
            st, p, s, ring = lanes.board[lane], lanes.params[lane], lanes.state[lane], lanes.ring[lane]
            for i in range(xl.shape[0]):
                xl[i] = lanes.x[i, k]
            q = work.q_start[k]
            while q < plan.shape[0]:
                row = plan[q]
                m = _plant_bin(xl, maps.io, f, n_bins)
                if m == n_bins:  # the block left the tables: BatchTwin builds more bins
                    work.need_bin[k] = int(np.rint(output(maps.io[0], 1, xl) * 2.0))
                    break
                n, s0 = row.n_ticks, row.first_sample
                n_pulses, n_seen = _plant_pulses(st, row, f, pulses, ring)
                a, b = pulses[seen, 0], pulses[seen, 1]
                st.acc += _sample_sum(st, xl, maps.px, maps.pdd, maps.rows, maps.chord_x, maps.chord_sum, maps.chord_d,
                                      maps.chord_rows, m, row.kind, s0, n, n_seen, a, b, adc.edges, f, scratch.ys,
                                      noise.noise_lsb[lane], noise.z[noise.streams[lane]], row.z_first, adc.slopes,
                                      adc.bounds, adc.sensor_p)
                _latch(st, row.first_wrap, row.last_phase, n)
                pins_before = st.pins
                if row.reading:
                    raw, st.acc = st.acc, 0
                    in_range = _protect(st, raw, row.millis, adc.lut, f)
                    if f.probe and in_range and tuned(p, s, st.temp_q5, target):
                        work.need_bin[k] = PROBED  # its state is left mid-period
                        break
                    st.amount = step(p, s, st.temp_q5, target, _board_inputs(inputs, st, f, row)) >> 1 \
                        if in_range else 0
                    _watch(st, st.temp_q5, target, row.millis, f)
                _advance(xl, xn, maps.fx, maps.fdd, maps.steps, m, row.kind, n, n_seen, a, b)
                _end_period(st, ring, xl, xn, maps.io[m, 0], f, pins_before)
                if row.reading:
                    _reading(st, score, lane, f, row, maps.io, m, xl, records)
                q += 1
            work.stop[k] = q
            for i in range(xl.shape[0]):
                lanes.x[i, k] = xl[i]

    folder = law_cache_folder(f"{law.step.__module__}.{law.name}", source, law.step) if numba is not None else None
    return jit(run_lanes, folder)


def law_source(law: LaneLaw) -> int:
    """A hash of what the law's compiled step is made of (``source_hash`` of its step and its ``tuned``). numba
    keys a cached function by its own file only; this key makes an edited law compile afresh."""
    return source_hash(law.step, law.tuned or never_tuned)
