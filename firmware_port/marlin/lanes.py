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

from firmware_port.fixed_lanes import div_round, trunc_c
from firmware_port.lane_law import ScalarLanes
from firmware_port.marlin.adc import AdcSequencer
from firmware_port.marlin.constants import ticks_to_ms, SOFT_PWM_PERIOD_TICKS
from firmware_port.marlin.pid import PREV_TEMP_EVERY_SAMPLE, PidGains, PidLanes
from firmware_port.marlin.protection import HeaterWatch, RunawayMonitor, TempRange
from firmware_port.thermistor import B3950_TABLE, TEMP_FRAC_BITS, TempTable

INACTIVE, FIRST_HEATING, STABLE, RUNAWAY = 0, 1, 2, 3
# What a lane died of: codes into TRIP_TEXTS (the TempError texts), 0 while it runs.
MAXTEMP_TRIP, MINTEMP_TRIP, RUNAWAY_TRIP, WATCH_TRIP = 1, 2, 3, 4
TRIP_TEXTS = ("", "MAXTEMP triggered", "MINTEMP triggered", "Thermal Runaway", "Heating failed")


def lookup_q5(table: TempTable, raw: np.ndarray) -> np.ndarray:
    """``TempTable.lookup_q5`` on lanes: any bracket holding raw gives the same value."""
    raws = np.asarray(table.raw, dtype=np.int64)
    temps = np.asarray(table.temp_q5, dtype=np.int64)
    hi = np.clip(np.searchsorted(raws, raw), 1, len(raws) - 1)
    v0, v1, t0, t1 = raws[hi - 1], raws[hi], temps[hi - 1], temps[hi]
    value = t0 + div_round((raw - v0) * (t1 - t0), v1 - v0)
    return np.where(raw <= raws[0], temps[0], np.where(raw >= raws[-1], temps[-1], value))


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
