"""The integer hotend firmware vectorised over N lanes (numpy int64), for batch twins.

Each lane is one board running a controller on a hotend: ``PidFixed`` with its own gains, vectorised
(``PidLanes``), or any other controller as one scalar instance per lane (``ScalarLanes``). All lanes share the
clock, so the ADC schedule and the soft-PWM counter are common (``AdcSequencer`` accumulates
arrays as happily as ints); amounts, pins, controller and protection state are per lane. numpy's
int64 shifts are arithmetic like avr-gcc's and every value fits the widths ``PidFixed``
declares (its property tests prove the bounds), so each lane computes exactly what the scalar
firmware computes; tests/firmware_port/marlin/test_lanes.py keeps them equal. A lane that trips its protection
(MAXTEMP, MINTEMP, runaway, heating watch) is halted with its heater off, as a killed board.
``millis()`` is not wrapped: a batch run is far shorter than 49 days.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from firmware_port.marlin.adc import AdcSequencer
from firmware_port.marlin.constants import SOFT_PWM_PERIOD_TICKS, ticks_to_ms
from firmware_port.marlin.pid import (
    D_FILTER_DIVISOR,
    D_RAW_LIMIT_Q8,
    D_SHIFT,
    FUNCTIONAL_RANGE_Q5,
    I_SHIFT,
    KD_Q16,
    KI_Q24,
    KP_Q12,
    OUT_FRAC_BITS,
    OUT_MAX_Q8,
    P_SHIFT,
    PREV_TEMP_EVERY_SAMPLE,
    PREV_TEMP_IN_BAND,
    PidFixed,
    PidGains,
    i_max_q5,
)
from firmware_port.marlin.protection import HeaterWatch, RunawayMonitor, TempRange
from firmware_port.thermistor import B3950_TABLE, TEMP_FRAC_BITS, TempTable

INACTIVE, FIRST_HEATING, STABLE, RUNAWAY = 0, 1, 2, 3
# What a lane died of: codes into TRIP_TEXTS (the TempError texts), 0 while it runs.
MAXTEMP_TRIP, MINTEMP_TRIP, RUNAWAY_TRIP, WATCH_TRIP = 1, 2, 3, 4
TRIP_TEXTS = ("", "MAXTEMP triggered", "MINTEMP triggered", "Thermal Runaway", "Heating failed")


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


def lookup_q5(table: TempTable, raw: np.ndarray) -> np.ndarray:
    """``TempTable.lookup_q5`` on lanes: any bracket holding raw gives the same value."""
    raws = np.asarray(table.raw, dtype=np.int64)
    temps = np.asarray(table.temp_q5, dtype=np.int64)
    hi = np.clip(np.searchsorted(raws, raw), 1, len(raws) - 1)
    v0, v1, t0, t1 = raws[hi - 1], raws[hi], temps[hi - 1], temps[hi]
    value = t0 + div_round((raw - v0) * (t1 - t0), v1 - v0)
    return np.where(raw <= raws[0], temps[0], np.where(raw >= raws[-1], temps[-1], value))


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
        i_sum = np.clip(i_sum + e, 0, self.i_max_q5)
        p = shr_round(self.kp_q12 * e, P_SHIFT)
        i = shr_round(self.ki_q24 * i_sum, I_SHIFT)
        d_in = np.clip(shr_round(self.kd_q16 * (self.prev_q5 - temp_q5), D_SHIFT), -D_RAW_LIMIT_Q8, D_RAW_LIMIT_Q8)
        d_term = d_term + div_round(d_in - d_term, D_FILTER_DIVISOR)
        self.i_sum_q5 = np.where(band, i_sum, self.i_sum_q5)
        self.d_term_q8 = np.where(band, d_term, self.d_term_q8)
        self.prev_q5 = np.where(np.where(self.every_sample, active, band), temp_q5, self.prev_q5)
        in_band = np.clip(p + i + d_term, 0, OUT_MAX_Q8)
        return np.where(full, OUT_MAX_Q8, np.where(band, in_band, 0))

    def output(self, temp_q5: np.ndarray, target_c: int, active: np.ndarray, now_ms: int) -> np.ndarray:
        """``PidFixed.update`` on the active lanes: 0..255 (0 elsewhere)."""
        return self.update_q8(temp_q5, target_c, active) >> OUT_FRAC_BITS


class ScalarLanes:
    """Any controller on N lanes, one instance per lane called in turn: the numpy lanes' way to run a law
    that is not vectorised (the compiled batch kernel has its own copy of each law it runs)."""

    def __init__(self, controllers: Sequence):
        self.controllers = list(controllers)

    def output(self, temp_q5: np.ndarray, target_c: int, active: np.ndarray, now_ms: int) -> np.ndarray:
        """Each active lane's ``update``: 0..255 (0 elsewhere, where its controller is not called)."""
        out = np.zeros(len(self.controllers), np.int64)
        for lane in np.flatnonzero(active):
            out[lane] = self.controllers[lane].update(int(temp_q5[lane]), target_c, now_ms)
        return out


@functools.lru_cache(maxsize=8)
def _hotend_range(table: TempTable) -> TempRange:
    """The hotend's limits on a table (the lanes only read them)."""
    return TempRange.hotend(table)


class HotendLanes:
    """N hotend boards: shared ISR clock, per-lane soft PWM, controller and protection.

    ``control``: PID gains (one set per lane, run as ``PidLanes`` in ``prev_temp_mode``), or a
    ``PidLanes`` or ``ScalarLanes``."""

    def __init__(self, control: list[PidGains] | PidLanes | ScalarLanes,
                 prev_temp_mode: str | Sequence[str] = PREV_TEMP_EVERY_SAMPLE, table: TempTable = B3950_TABLE):
        if isinstance(control, list):
            control = PidLanes(control, prev_temp_mode)
        self.control = control
        n = len(control.every_sample) if isinstance(control, PidLanes) else len(control.controllers)
        self.n_lanes = n
        self.table = table
        self.adc = AdcSequencer(1, port=None)
        self.temp_range = _hotend_range(table)
        runaway, watch = RunawayMonitor.hotend(), HeaterWatch.hotend()
        self.runaway_period_ms, self.runaway_hysteresis_c = runaway.period_s * 1000, runaway.hysteresis_c
        self.watch_increase_c, self.watch_hysteresis_c = watch.increase_c, watch.hysteresis_c
        self.watch_period_ms = watch.period_s * 1000
        self.ticks = 0
        self.pwm_count = 1  # shared soft-PWM counter
        self.amount = np.zeros(n, np.int64)
        self.count = np.zeros(n, np.int64)
        self.pins = np.zeros(n, bool)
        self.target_c = 0
        self.temp_q5 = np.zeros(n, np.int64)
        self.halted = np.zeros(n, bool)
        self.trip_code = np.zeros(n, np.int64)
        self.runaway_state = np.full(n, INACTIVE)
        self.runaway_c = 0
        self.runaway_timer_ms = np.zeros(n, np.int64)
        self.watch_target_c = np.zeros(n, np.int64)
        self.watch_next_ms = np.zeros(n, np.int64)

    @property
    def trip(self) -> np.ndarray:
        """The TempError text each lane died of ("" while it runs)."""
        return np.array(TRIP_TEXTS, dtype=object)[self.trip_code]

    @property
    def now_ms(self) -> int:
        return ticks_to_ms(self.ticks)

    def set_target(self, target_c: int) -> None:
        """M104 on every lane: clamp, restart the heating watch from each lane's temperature."""
        self.target_c = self.temp_range.clamp_target(target_c)
        cur = trunc_c(self.temp_q5) + self.watch_increase_c
        armed = (self.target_c != 0) & (cur < self.target_c - self.watch_hysteresis_c - 1)
        self.watch_target_c = np.where(armed, cur, self.watch_target_c)
        self.watch_next_ms = np.where(armed, self.now_ms + self.watch_period_ms, 0)

    # -- ISR in closed form ---------------------------------------------------------------
    def pulses(self, n_ticks: int) -> list[tuple]:
        """``SoftPwm.waveform`` as heater pulses: per lane, high on ticks [alpha, beta) of each pair.

        Before the first wrap a lane can only finish its current pulse (at the old latched
        count); after each wrap it is high for ``amount`` ticks.
        """
        first_wrap = (SOFT_PWM_PERIOD_TICKS - self.pwm_count) % SOFT_PWM_PERIOD_TICKS
        tail_end = np.clip(self.count - self.pwm_count, 0, min(first_wrap, n_ticks))
        pulses = [(0, np.where(self.pins, tail_end, 0))]
        for wrap in range(first_wrap, n_ticks, SOFT_PWM_PERIOD_TICKS):
            pulses.append((wrap, np.minimum(wrap + self.amount, n_ticks)))
        return pulses

    def skip(self, n_ticks: int, samples: np.ndarray) -> None:
        """n ISRs at once given the hotend samples (J, N) at ``adc.sample_offsets(n)[0]``."""
        first_wrap = (SOFT_PWM_PERIOD_TICKS - self.pwm_count) % SOFT_PWM_PERIOD_TICKS
        last = (self.pwm_count + n_ticks - 1) % SOFT_PWM_PERIOD_TICKS
        if first_wrap < n_ticks:
            self.count = self.amount.copy()
            self.pins = last < self.amount
        else:
            self.pins = self.pins & (last < self.count)
        self.pwm_count = last + 1
        self.adc.skip(n_ticks, [samples])
        self.ticks += n_ticks
        self.pins &= ~self.halted

    # -- the main loop on a fresh reading ----------------------------------------------------
    def task(self) -> None:
        """updateTemperaturesFromRawValues + manage_hotends on every live lane."""
        if not self.adc.raw_ready:
            return
        raw = np.asarray(self.adc.raw[0], dtype=np.int64)
        self.adc.raw_ready = False
        live = ~self.halted
        self.temp_q5 = np.where(live, lookup_q5(self.table, raw), self.temp_q5)
        limits, now, temp, target = self.temp_range, self.now_ms, self.temp_q5, self.target_c
        self._trip(live & (raw < limits.raw_max), MAXTEMP_TRIP)
        self._trip(~self.halted & (target > 0) & (raw > limits.raw_min), MINTEMP_TRIP)
        self._trip(~self.halted & (temp > limits.maxtemp_c << TEMP_FRAC_BITS), MAXTEMP_TRIP)
        self._trip(~self.halted & self._runaway(temp, target, now), RUNAWAY_TRIP)
        live = ~self.halted
        in_range = live & (temp > limits.mintemp_c << TEMP_FRAC_BITS) & (temp < limits.maxtemp_c << TEMP_FRAC_BITS)
        self.amount = np.where(in_range, self.control.output(temp, target, in_range, now) >> 1, 0)
        self._trip(~self.halted & self._heating_failed(temp, target, now), WATCH_TRIP)

    def _trip(self, lanes: np.ndarray, code: int) -> None:
        """_temp_error on some lanes: heater off, board halted."""
        if lanes.any():
            self.trip_code = np.where(lanes, code, self.trip_code)
            self.halted |= lanes
            self.amount = np.where(lanes, 0, self.amount)
            self.count = np.where(lanes, 0, self.count)
            self.pins &= ~lanes

    def _runaway(self, temp: np.ndarray, target: int, now: int) -> np.ndarray:
        """``RunawayMonitor.run`` per lane; the target is common to all lanes."""
        if self.runaway_c != target:
            self.runaway_c = target
            self.runaway_state = np.where(~self.halted, FIRST_HEATING if target > 0 else INACTIVE, self.runaway_state)
        state = self.runaway_state
        state = np.where((state == FIRST_HEATING) & (temp >= target << TEMP_FRAC_BITS), STABLE, state)
        stable = state == STABLE
        ok = stable & (temp >= (target - self.runaway_hysteresis_c) << TEMP_FRAC_BITS)
        self.runaway_timer_ms = np.where(ok, now + self.runaway_period_ms, self.runaway_timer_ms)
        tripped = stable & ~ok & (now >= self.runaway_timer_ms)
        self.runaway_state = np.where(tripped, RUNAWAY, state)
        return self.runaway_state == RUNAWAY

    def _heating_failed(self, temp: np.ndarray, target: int, now: int) -> np.ndarray:
        """``HeaterWatch.heating_failed`` per lane: re-arm from the current temperature if risen enough."""
        elapsed = (self.watch_next_ms != 0) & (now >= self.watch_next_ms)
        risen = trunc_c(temp) >= self.watch_target_c
        rearm = elapsed & risen
        if rearm.any():
            cur = trunc_c(temp) + self.watch_increase_c
            armed = (target != 0) & (cur < target - self.watch_hysteresis_c - 1)
            self.watch_target_c = np.where(rearm & armed, cur, self.watch_target_c)
            self.watch_next_ms = np.where(rearm, np.where(armed, now + self.watch_period_ms, 0), self.watch_next_ms)
        return elapsed & ~risen
