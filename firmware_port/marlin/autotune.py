"""M303 PID autotune: Marlin's relay (bias/d) oscillation and its Ziegler-Nichols gains.

Marlin runs M303 as one blocking while loop (`Temperature::PID_autotune`); here one `poll()`
is one pass of that loop, so the board can drive it from its own clock. Each pass does, in
Marlin's order: on a fresh reading, min/max tracking and the relay switch (at most one switch
each way, each half cycle at least 5 s); the overshoot abort; the 2 s heater report and the
heating watch inside it; the 20 min timeout; the finish.

Sources: MarlinFirmware/Marlin bugfix-2.1.x (000b347) Marlin/src/module/temperature.cpp
`PID_autotune` and Marlin/src/core/language.h (STR_PID_*, STR_BIAS ...); for the "1.1" option
the spring-2017 1.1.x Marlin/temperature.cpp (the firmware that printed the capture
m303_hotend_C1_degenerate_marlin6316.txt).

Units: temperatures celsius_q5 (1/32 degC), targets whole degC, times millis(). Marlin keeps
the temperatures in float; a celsius_q5 value converts to float32 exactly, so comparisons and
min/max are done on the integers and only Ku/Tu/Kp/Ki/Kd use numpy.float32.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from firmware_port.fixed import c_div, clamp, wrap_u32
from firmware_port.marlin.constants import (
    BED_OVERSHOOT_C,
    HOTEND_OVERSHOOT_C,
    MAX_BED_POWER,
    MAX_CYCLE_TIME_PID_AUTOTUNE_MIN,
    MAX_OVERSHOOT_PID_AUTOTUNE_C,
    PID_MAX,
    TEMP_BED_HYSTERESIS_C,
    TEMP_HYSTERESIS_C,
    WATCH_BED_TEMP_INCREASE_C,
    WATCH_BED_TEMP_PERIOD_S,
    WATCH_TEMP_INCREASE_C,
    WATCH_TEMP_PERIOD_S,
)
from firmware_port.marlin.protection import TempError, time_elapsed
from firmware_port.marlin.serial import Console, format_float
from firmware_port.marlin.versions import DEFAULT_VERSION, MarlinVersion
from firmware_port.thermistor import TEMP_ONE

_F32 = np.float32

MIN_HALF_CYCLE_MS = 5000  # ELAPSED(ms, t2 + 5000UL) / ELAPSED(ms, t1 + 5000UL)
REPORT_INTERVAL_MS = 2000  # "Report heater states every 2 seconds"
BIAS_MARGIN = 20  # LIMIT(bias, 20, max_pow - 20)
TIMEOUT_MS = MAX_CYCLE_TIME_PID_AUTOTUNE_MIN * 60 * 1000
MAX_OVERSHOOT_PID_AUTOTUNE_1_1_C = 20  # 1.1.x: #define MAX_OVERSHOOT_PID_AUTOTUNE 20

# core/language.h (2.1.x); 1.1.x printed the same text.
STR_PID_AUTOTUNE_START = "PID Autotune start"
STR_PID_TEMP_TOO_HIGH = "PID Autotune failed! Temperature too high"
STR_PID_TIMEOUT = "PID Autotune failed! timeout"
STR_PID_AUTOTUNE_FINISHED = (
    "PID Autotune finished! Put the last Kp, Ki and Kd constants from below into Configuration.h"
)
STR_CLASSIC_PID = " Classic PID "  # with its trailing space
STR_NO_OVERSHOOT = " No overshoot"  # a literal in temperature.cpp, no trailing space


@dataclass(frozen=True)
class VersionRules:
    """Where the Marlin versions' M303 loops differ."""

    min_cycles: int  # 2.1: finish needs `cycles > 2` as well as `cycles > ncycles`
    define_prefix: str  # the result lines; 1.1 printed two spaces
    bed_no_overshoot: bool  # 2.x tunes beds with Kp = 0.2 Ku, Kd = Kp Tu / 3
    max_overshoot_c: int  # abort above target + this
    first_report_ms: int  # 2.1 reports at once; 1.1 first after 2 s
    target_check: bool  # 2.1 refuses target > maxtemp - overshoot before starting
    watch: bool  # 2.1 runs the heating watch inside the loop
    abort_disables_heaters: bool  # 2.1 `break`s to disable_all_heaters(); 1.1 `return`s
    timeout_sums_both: bool  # 1.1: (ms - t1) + (ms - t2); 2.1: ms - min(t1, t2)


VERSIONS = {
    MarlinVersion.V2_1: VersionRules(
        min_cycles=3,
        define_prefix="#define DEFAULT_",
        bed_no_overshoot=True,
        max_overshoot_c=MAX_OVERSHOOT_PID_AUTOTUNE_C,
        first_report_ms=0,
        target_check=True,
        watch=True,
        abort_disables_heaters=True,
        timeout_sums_both=False,
    ),
    MarlinVersion.V1_1: VersionRules(
        min_cycles=0,
        define_prefix="#define  DEFAULT_",
        bed_no_overshoot=False,
        max_overshoot_c=MAX_OVERSHOOT_PID_AUTOTUNE_1_1_C,
        first_report_ms=REPORT_INTERVAL_MS,
        target_check=False,
        watch=False,
        abort_disables_heaters=False,
        timeout_sums_both=True,
    ),
}


def update_bias(bias: int, d: int, t_high_ms: int, t_low_ms: int,
                max_pow: int) -> tuple[int, int]:
    """The relay adaptation at each switch-on: `long` maths, the division truncates toward zero.

    bias moves to balance the heating and cooling times, is clamped to [20, max_pow - 20], and
    d is the largest swing around it that stays inside 0..max_pow - 1.
    """
    bias = clamp(bias + c_div(d * (t_high_ms - t_low_ms), t_low_ms + t_high_ms),
                 BIAS_MARGIN, max_pow - BIAS_MARGIN)
    d = max_pow - 1 - bias if bias > max_pow >> 1 else bias
    return bias, d


def relay_levels(bias: int, d: int) -> tuple[int, int]:
    """Soft-PWM amounts (0..127) while heating and while cooling: (bias +- d) >> 1."""
    return (bias + d) >> 1, (bias - d) >> 1


def ultimate_gain(d: int, min_c: float, max_c: float) -> np.float32:
    """Ku = 4 d / (pi a), a = half the peak-to-peak swing, in Marlin's float32 order."""
    half_swing = _F32(np.pi) * (_F32(max_c) - _F32(min_c)) * _F32(0.5)
    return _F32(4.0) * _F32(d) / half_swing


def pid_from_relay(ku: np.float32 | np.ndarray, period_ms: int, no_overshoot: bool) -> tuple:
    """(Tu, Kp, Ki, Kd) in user units from Ku and Tu = t_low + t_high, all float32.

    "Classic PID": Kp = 0.6 Ku, Ki = 2 Kp / Tu, Kd = Kp Tu / 8; "No overshoot" (2.x beds):
    Kp = 0.2 Ku, Kd = Kp Tu / 3. Works on float32 arrays of Ku as well.
    """
    tu = _F32(period_ms) * _F32(0.001)
    if no_overshoot:
        pf, df = _F32(0.2), _F32(1.0) / _F32(3.0)
    else:
        pf, df = _F32(0.6), _F32(1.0) / _F32(8.0)
    kp = ku * pf
    return tu, kp, kp * _F32(2.0) / tu, kp * tu * df


def relay_gains(d: int, min_c: float, max_c: float, period_ms: int,
                no_overshoot: bool) -> tuple[np.float32, ...]:
    """(Ku, Tu, Kp, Ki, Kd) of one relay cycle, as Marlin computes and prints them."""
    ku = ultimate_gain(d, min_c, max_c)
    return (ku, *pid_from_relay(ku, period_ms, no_overshoot))


class Autotune:
    """Marlin's M303 for one heater, one pass of its while loop per `poll()`.

    The board reads `amount` (the tuned heater's soft-PWM, 0..127) after every call, and stops
    calling once `done`. After a success (and after "1.1"'s overshoot or timeout abort, which
    returned) `amount` keeps the last relay level, as Marlin leaves soft_pwm_amount until the
    next manage_heater pass (all targets are 0 by then); after a 2.1 abort, a temperature
    error or `cancel()` it is 0 (disable_all_heaters). `heater_states` is called inside
    `poll`, after `amount` changed in the same pass, and must show it (Marlin's @: field).
    `gains` is None until a finish; then the printed Kp, Ki, Kd (user units), which are zeros
    when the run ended before the 4th switch-on computed any (C < 3; M303 U1 would apply them).
    """

    def __init__(
        self,
        heater_id: int,
        target_c: int,
        ncycles: int,
        is_bed: bool,
        console: Console,
        heater_states: Callable[[], str],
        temp_error: Callable[[str], None],
        maxtemp_c: int,
        version: str = DEFAULT_VERSION,
    ) -> None:
        if version not in VERSIONS:
            raise ValueError(f"unknown Marlin version {version!r}; expected {list(VERSIONS)}")
        self.heater_id = heater_id  # Marlin's heater_id_t: hotend index, or H_BED (-1)
        self.target_c = target_c
        self.ncycles = ncycles
        self.is_bed = is_bed
        self.console = console
        self.heater_states = heater_states
        self.temp_error = temp_error
        self.rules = VERSIONS[MarlinVersion(version)]
        self.max_target_c = maxtemp_c - (BED_OVERSHOOT_C if is_bed else HOTEND_OVERSHOOT_C)
        self.max_pow = MAX_BED_POWER if is_bed else PID_MAX
        self.no_overshoot = is_bed and self.rules.bed_no_overshoot
        if is_bed:
            increase_c, hysteresis_c, period_s = (
                WATCH_BED_TEMP_INCREASE_C, TEMP_BED_HYSTERESIS_C, WATCH_BED_TEMP_PERIOD_S)
        else:
            increase_c, hysteresis_c, period_s = (
                WATCH_TEMP_INCREASE_C, TEMP_HYSTERESIS_C, WATCH_TEMP_PERIOD_S)
        self.watch_increase_q5 = increase_c * TEMP_ONE
        self.watch_period_ms = period_s * 1000
        self.watch_target_q5 = (target_c - (increase_c + hysteresis_c + 1)) * TEMP_ONE

        self.bias = self.d = 0  # long, 0..max_pow
        self.heating = True
        self.cycles = 0
        self.t1_ms = self.t2_ms = 0  # millis_t: last switch-off, last switch-on
        self.t_high_ms = self.t_low_ms = 0  # long
        self.current_q5 = 0  # current_temp: 0.0 until the first fresh reading
        self.max_q5, self.min_q5 = 0, 10000 * TEMP_ONE  # maxT, minT
        self.next_report_ms = 0
        self.heated = False
        self.next_watch_q5 = 0
        self.temp_change_ms = 0
        self.tune = (_F32(0.0), _F32(0.0), _F32(0.0))  # tune_pid: the last Kp, Ki, Kd

        self.amount = 0
        self.done = False
        self.succeeded = False
        self.gains: tuple[float, float, float] | None = None


    def __repr__(self) -> str:
        heater = "bed" if self.is_bed else f"E{self.heater_id}"
        return f"Autotune(M303 {heater} S{self.target_c} C{self.ncycles}, done={self.done}, gains={self.gains})"
    def start(self, now_ms: int) -> None:
        """Marlin's code before the loop; the board runs disable_all_heaters() unless `done`.

        Marlin's current_temp starts at 0.0 and only a fresh reading in `poll` sets it (which
        matters for the first heating watch).
        """
        self.t1_ms = self.t2_ms = now_ms
        self.next_report_ms = now_ms + self.rules.first_report_ms
        self.temp_change_ms = now_ms + self.watch_period_ms
        if self.rules.target_check and self.target_c > self.max_target_c:
            self.console.writeln(STR_PID_TEMP_TOO_HIGH)
            self.done = True  # Marlin returns here, before disable_all_heaters()
            return
        self.console.writeln(STR_PID_AUTOTUNE_START)
        self.bias = self.d = self.max_pow >> 1
        self.amount = self.bias

    def cancel(self) -> None:
        """M108: wait_for_heatup = false ends the loop before its next pass; heaters off."""
        if not self.done:
            self._end(heaters_off=True)

    def poll(self, now_ms: int, temp_q5: int | None) -> None:
        """One pass of the loop; temp_q5 only when a fresh reading arrived, else None."""
        if self.done:
            return
        if temp_q5 is not None:
            self._sample(now_ms, temp_q5)

        if self.current_q5 > (self.target_c + self.rules.max_overshoot_c) * TEMP_ONE:
            self.console.writeln(STR_PID_TEMP_TOO_HIGH)
            self._end(heaters_off=self.rules.abort_disables_heaters)
            return

        if time_elapsed(now_ms, self.next_report_ms):
            self.console.writeln(self.heater_states())
            self.next_report_ms = now_ms + REPORT_INTERVAL_MS
            error = self._watch(now_ms) if self.rules.watch else None
            if error is not None:
                self.temp_error(error)
                self._end(heaters_off=True)  # _temp_error: disable_all_heaters(), then kill()
                return

        if self._since_cycle_ms(now_ms) > TIMEOUT_MS:
            self.console.writeln(STR_PID_TIMEOUT)
            self._end(heaters_off=self.rules.abort_disables_heaters)
            return

        if self.cycles > self.ncycles and self.cycles >= self.rules.min_cycles:
            self._finish()

    def next_deadline_ms(self) -> int:
        """The next time a pass without a fresh reading can act: the 2 s report or the timeout."""
        if self.rules.timeout_sums_both:  # (now - t1) + (now - t2) > TIMEOUT
            timeout_ms = (TIMEOUT_MS + self.t1_ms + self.t2_ms) // 2 + 1
        else:
            timeout_ms = min(self.t1_ms, self.t2_ms) + TIMEOUT_MS + 1
        return min(self.next_report_ms, timeout_ms)

    def _sample(self, now_ms: int, temp_q5: int) -> None:
        """A fresh reading: track min/max and switch the relay."""
        self.current_q5 = temp_q5
        self.max_q5 = max(self.max_q5, temp_q5)
        self.min_q5 = min(self.min_q5, temp_q5)
        target_q5 = self.target_c * TEMP_ONE

        if (self.heating and temp_q5 > target_q5
                and time_elapsed(now_ms, self.t2_ms + MIN_HALF_CYCLE_MS)):
            self.heating = False
            self.amount = relay_levels(self.bias, self.d)[1]
            self.t1_ms = now_ms
            self.t_high_ms = self.t1_ms - self.t2_ms
            self.max_q5 = target_q5  # catch the overshoot still to come

        if (not self.heating and temp_q5 < target_q5
                and time_elapsed(now_ms, self.t1_ms + MIN_HALF_CYCLE_MS)):
            self.heating = True
            self.t2_ms = now_ms
            self.t_low_ms = self.t2_ms - self.t1_ms
            if self.cycles > 0:
                self.bias, self.d = update_bias(
                    self.bias, self.d, self.t_high_ms, self.t_low_ms, self.max_pow)
                # No newline: from cycle 3 the Ku line completes it, before that whatever
                # Marlin prints next (usually the 2 s report) lands on the same line.
                self.console.write(
                    f" bias: {self.bias} d: {self.d} min: {_fmt_q5(self.min_q5)}"
                    f" max: {_fmt_q5(self.max_q5)}")
                if self.cycles > 2:
                    self._print_gains()
            self.amount = relay_levels(self.bias, self.d)[0]
            self.cycles += 1
            self.min_q5 = target_q5

    def _print_gains(self) -> None:
        ku, tu, kp, ki, kd = relay_gains(
            self.d, self.min_q5 / TEMP_ONE, self.max_q5 / TEMP_ONE,
            self.t_low_ms + self.t_high_ms, self.no_overshoot)
        self.tune = (kp, ki, kd)
        self.console.writeln(f" Ku: {format_float(ku)} Tu: {format_float(tu)}")
        self.console.writeln(STR_NO_OVERSHOOT if self.no_overshoot else STR_CLASSIC_PID)
        self.console.writeln(
            f" Kp: {format_float(kp)} Ki: {format_float(ki)} Kd: {format_float(kd)}")

    def _watch(self, now_ms: int) -> TempError | None:
        """The heating check of the 2 s report: the error to raise, if any."""
        if not self.heated:
            if self.current_q5 > self.next_watch_q5:
                self.next_watch_q5 = self.current_q5 + self.watch_increase_q5
                self.temp_change_ms = now_ms + self.watch_period_ms
                self.heated = self.current_q5 > self.watch_target_q5
            elif time_elapsed(now_ms, self.temp_change_ms):
                return TempError.HEATING_FAILED
        elif self.current_q5 < (self.target_c - self.rules.max_overshoot_c) * TEMP_ONE:
            return TempError.THERMAL_RUNAWAY
        return None

    def _since_cycle_ms(self, now_ms: int) -> int:
        """The timeout clock, as unsigned millis_t arithmetic."""
        if self.rules.timeout_sums_both:
            return wrap_u32(wrap_u32(now_ms - self.t1_ms) + wrap_u32(now_ms - self.t2_ms))
        return wrap_u32(now_ms - min(self.t1_ms, self.t2_ms))

    def _finish(self) -> None:
        self.console.writeln(STR_PID_AUTOTUNE_FINISHED)
        heater = "bed" if self.is_bed else ""
        for name, value in zip(("Kp", "Ki", "Kd"), self.tune):
            self.console.writeln(f"{self.rules.define_prefix}{heater}{name} {format_float(value)}")
        kp, ki, kd = self.tune
        self.gains = (float(kp), float(ki), float(kd))
        self.succeeded = True
        self.done = True

    def _end(self, heaters_off: bool) -> None:
        if heaters_off:
            self.amount = 0
        self.done = True


def _fmt_q5(temp_q5: int) -> str:
    return format_float(temp_q5 / TEMP_ONE)

