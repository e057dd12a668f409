"""Marlin 2.1.x thermal protection: runaway, heating watch, MIN/MAXTEMP, and what a host reads.

Sources (MarlinFirmware/Marlin bugfix-2.1.x): module/temperature.h (HeaterWatch, temp_range_t,
tr_state_machine_t, setTargetHotend/Bed), module/temperature.cpp (tr_state_machine_t::run,
manage_hotends, manage_heated_bed, updateTemperaturesFromRawValues, init, _temp_error,
loud_kill), MarlinCore.cpp (kill, minkill, M112_KILL_STR), core/language.h (STR_*),
lcd/language/language_en.h (MSG_*).

Marlin checks, on each fresh sample, in this order:
1. updateTemperaturesFromRawValues: hotend raw MAXTEMP, raw MINTEMP (if the heater is on),
   then the bed's raw MAXTEMP and MINTEMP;
2. manage_hotends: MAXTEMP on the converted temperature, the runaway monitor, then the watch;
3. manage_heated_bed: MAXTEMP on the converted temperature, the watch, then (inside the 5 s
   bang-bang gate) the runaway monitor.
The first error prints `temp_error_text` and halts the board for good.

Units: temperatures are celsius_q5 (1/32 degC), targets celsius_t whole degrees, time millis().
"""

from __future__ import annotations

from enum import Enum, StrEnum

from firmware_port.fixed import c_div, wrap_s32, wrap_u32
from firmware_port.marlin.constants import (
    BED_MAXTEMP_C,
    BED_MINTEMP_C,
    BED_OVERSHOOT_C,
    HEATER_0_MAXTEMP_C,
    HEATER_0_MINTEMP_C,
    HOTEND_OVERSHOOT_C,
    TEMP_BED_HYSTERESIS_C,
    TEMP_HYSTERESIS_C,
    THERMAL_PROTECTION_BED_HYSTERESIS_C,
    THERMAL_PROTECTION_BED_PERIOD_S,
    THERMAL_PROTECTION_HYSTERESIS_C,
    THERMAL_PROTECTION_PERIOD_S,
    WATCH_BED_TEMP_INCREASE_C,
    WATCH_BED_TEMP_PERIOD_S,
    WATCH_TEMP_INCREASE_C,
    WATCH_TEMP_PERIOD_S,
)
from firmware_port.marlin.versions import DEFAULT_VERSION, MarlinVersion
from firmware_port.thermistor import TEMP_ONE, TempTable

H_BED = -1  # heater id of the bed; hotends are 0, 1, ... (Marlin's heater_id_t)
VERSIONS = (MarlinVersion.V2_1, MarlinVersion.V2_0)  # 2.1 is the default everywhere


def time_pending(now_ms: int, deadline_ms: int) -> bool:
    """Marlin's PENDING(now, soon): the deadline is ahead, by the signed 32-bit difference."""
    return wrap_s32(now_ms - deadline_ms) < 0


def time_elapsed(now_ms: int, deadline_ms: int) -> bool:
    """Marlin's ELAPSED(now, soon): the deadline is reached or past (wraps like millis_t)."""
    return not time_pending(now_ms, deadline_ms)


def _deadline_ms(now_ms: int, period_s: int) -> int:
    """`millis() + SEC_TO_MS(period)` stored in a uint32 millis_t."""
    return wrap_u32(now_ms + period_s * 1000)


def _whole_c(temp_q5: int) -> int:
    """A float temperature passed as celsius_t: truncated toward zero, as C converts it."""
    return c_div(temp_q5, TEMP_ONE)


class RunawayState(Enum):
    """tr_state_machine_t::TRState (no THERMAL_PROTECTION_VARIANCE_MONITOR, off by default)."""

    INACTIVE = 0
    FIRST_HEATING = 1
    STABLE = 2
    RUNAWAY = 3


class RunawayMonitor:
    """Thermal runaway: at target, a heater may not stay below target - hysteresis for period_s.

    There is no timeout while first heating up to a new target; HeaterWatch covers that phase.
    HEATER_IDLE_HANDLER (off by default) is not modelled.
    """

    def __init__(self, period_s: int, hysteresis_c: int) -> None:
        self.period_s = period_s
        self.hysteresis_c = hysteresis_c
        self.state = RunawayState.INACTIVE
        self.running_c = 0  # running_temp: the watched target (a float in Marlin, whole degrees)
        self.timer_ms = 0  # timer: uint32 millis_t deadline while Stable

    def __repr__(self) -> str:
        return f"RunawayMonitor({self.period_s} s, {self.hysteresis_c} C, {self.state.name}, watching {self.running_c} C)"

    @classmethod
    def hotend(cls) -> RunawayMonitor:
        """THERMAL_PROTECTION_PERIOD 40 s, THERMAL_PROTECTION_HYSTERESIS 4 C."""
        return cls(THERMAL_PROTECTION_PERIOD_S, THERMAL_PROTECTION_HYSTERESIS_C)

    @classmethod
    def bed(cls) -> RunawayMonitor:
        """THERMAL_PROTECTION_BED_PERIOD 20 s, THERMAL_PROTECTION_BED_HYSTERESIS 2 C."""
        return cls(THERMAL_PROTECTION_BED_PERIOD_S, THERMAL_PROTECTION_BED_HYSTERESIS_C)

    def run(self, temp_q5: int, target_c: int, now_ms: int) -> bool:
        """One sample; True when Marlin calls _temp_error("Thermal Runaway").

        That is on the sample the monitor trips and, like the C switch, on every later sample
        until the target changes (a halted board never gets there).
        """
        if self.running_c != target_c:  # a new target restarts the machine
            self.running_c = target_c
            first = target_c > 0
            self.state = RunawayState.FIRST_HEATING if first else RunawayState.INACTIVE
        if self.state is RunawayState.FIRST_HEATING:
            if temp_q5 < self.running_c * TEMP_ONE:
                return False
            self.state = RunawayState.STABLE  # and fall through into Stable, as the C switch does
        if self.state is RunawayState.STABLE:
            if temp_q5 >= (self.running_c - self.hysteresis_c) * TEMP_ONE:
                self.timer_ms = _deadline_ms(now_ms, self.period_s)
                return False
            if time_pending(now_ms, self.timer_ms):
                return False
            self.state = RunawayState.RUNAWAY
        return self.state is RunawayState.RUNAWAY


class HeaterWatch:
    """Heating watch: while heating from far below target, rise increase_c every period_s.

    Armed by `restart` on every target change (Marlin's start_watching_* in setTarget*).
    """

    def __init__(self, increase_c: int, hysteresis_c: int, period_s: int) -> None:
        self.increase_c = increase_c
        self.hysteresis_c = hysteresis_c
        self.period_s = period_s
        self.target_c = 0  # celsius_t: the temperature to reach by the deadline
        # uint32 millis_t deadline; 0 means not watching (as in Marlin, even one wrapped to 0)
        self.next_ms = 0

    def __repr__(self) -> str:
        watching = f"to reach {self.target_c} C by {self.next_ms} ms" if self.next_ms else "idle"
        return f"HeaterWatch(+{self.increase_c} C per {self.period_s} s, {watching})"

    @classmethod
    def hotend(cls) -> HeaterWatch:
        """WATCH_TEMP_INCREASE 2 C per WATCH_TEMP_PERIOD 40 s, TEMP_HYSTERESIS 3 C."""
        return cls(WATCH_TEMP_INCREASE_C, TEMP_HYSTERESIS_C, WATCH_TEMP_PERIOD_S)

    @classmethod
    def bed(cls) -> HeaterWatch:
        """WATCH_BED_TEMP_INCREASE 2 C per WATCH_BED_TEMP_PERIOD 60 s, TEMP_BED_HYSTERESIS 3 C."""
        return cls(WATCH_BED_TEMP_INCREASE_C, TEMP_BED_HYSTERESIS_C, WATCH_BED_TEMP_PERIOD_S)

    def restart(self, temp_q5: int, target_c: int, now_ms: int) -> None:
        """Arm if target_c != 0 and cur + increase < target - hysteresis - 1 (cur truncated)."""
        if target_c:
            watch_target_c = _whole_c(temp_q5) + self.increase_c
            if watch_target_c < target_c - self.hysteresis_c - 1:
                self.target_c = watch_target_c
                self.next_ms = _deadline_ms(now_ms, self.period_s)
                return
        self.next_ms = 0

    def elapsed(self, now_ms: int) -> bool:
        """Watching, and the deadline has come."""
        return self.next_ms != 0 and time_elapsed(now_ms, self.next_ms)

    def check(self, temp_q5: int) -> bool:
        """The temperature (truncated to celsius_t) has reached the watch target."""
        return _whole_c(temp_q5) >= self.target_c

    def heating_failed(self, temp_q5: int, target_c: int, now_ms: int) -> bool:
        """One sample of manage_hotends/manage_heated_bed; True means raise "Heating failed".

        At the deadline a heater that rose enough is re-armed from its current temperature.
        """
        if not self.elapsed(now_ms):
            return False
        if self.check(temp_q5):
            self.restart(temp_q5, target_c, now_ms)
            return False
        return True


def heater_on(target_c: int, soft_pwm_amount: int = 0, *, version: str = DEFAULT_VERSION) -> bool:
    """Whether the hotend MINTEMP check applies.

    2.1.x: `target > 0`. 2.0.x also counted a PID hotend still driving its heater
    (`|| soft_pwm_amount > 0` under PIDTEMP): pass soft_pwm_amount only for such a hotend.
    Preheating (PREHEAT_TIME_HOTEND_MS, 0 by default) is not modelled.
    """
    _check_version(version)
    return target_c > 0 or (version == MarlinVersion.V2_0 and soft_pwm_amount > 0)


class TempRange:
    """MINTEMP/MAXTEMP for one heater on an NTC table (raw falls as it heats).

    As Marlin's init: for hotends the limits are first narrowed to what the table can read
    (mintemp >= its coldest row, maxtemp <= its hottest row - 1; the bed is not narrowed),
    then raw_min/raw_max are found by stepping raw by OVERSAMPLENR from the ends of the range.
    """

    def __init__(
        self,
        table: TempTable,
        mintemp_c: int,
        maxtemp_c: int,
        *,
        overshoot_c: int,
        limit_to_table: bool = True,
    ) -> None:
        # Marlin's max target uses the configured MAXTEMP, not the table-narrowed one.
        self.max_target_c = maxtemp_c - overshoot_c
        if limit_to_table:
            mintemp_c = max(mintemp_c, _whole_c(table.temp_q5[-1]))
            maxtemp_c = min(maxtemp_c, _whole_c(table.temp_q5[0]) - 1)
        self.mintemp_c = mintemp_c
        self.maxtemp_c = maxtemp_c
        self.raw_min = table.raw_threshold(mintemp_c, above=False)
        self.raw_max = table.raw_threshold(maxtemp_c, above=True)

    def __repr__(self) -> str:
        return f"TempRange({self.mintemp_c}..{self.maxtemp_c} C, raw {self.raw_max}..{self.raw_min}, " \
               f"max target {self.max_target_c} C)"

    @classmethod
    def hotend(cls, table: TempTable) -> TempRange:
        """HEATER_0_MINTEMP 5 C, HEATER_0_MAXTEMP 275 C, HOTEND_OVERSHOOT 15 C."""
        return cls(table, HEATER_0_MINTEMP_C, HEATER_0_MAXTEMP_C, overshoot_c=HOTEND_OVERSHOOT_C)

    @classmethod
    def bed(cls, table: TempTable) -> TempRange:
        """BED_MINTEMP 5 C, BED_MAXTEMP 150 C, BED_OVERSHOOT 10 C."""
        return cls(
            table, BED_MINTEMP_C, BED_MAXTEMP_C, overshoot_c=BED_OVERSHOOT_C, limit_to_table=False
        )

    def maxtemp_raw_tripped(self, raw: int) -> bool:
        """Raw MAXTEMP (updateTemperaturesFromRawValues); a shorted thermistor reads raw 0."""
        return raw < self.raw_max

    def mintemp_raw_tripped(self, raw: int, heater_on: bool) -> bool:
        """Raw MINTEMP, only while heating is requested; an open thermistor reads raw 16368."""
        return heater_on and raw > self.raw_min

    def maxtemp_tripped(self, temp_q5: int) -> bool:
        """MAXTEMP on the converted temperature (manage_hotends / manage_heated_bed)."""
        return temp_q5 > self.maxtemp_c * TEMP_ONE

    def clamp_target(self, target_c: int) -> int:
        """setTargetHotend/setTargetBed: targets above maxtemp - overshoot are lowered to it."""
        return min(target_c, self.max_target_c)


class TempError(StrEnum):
    """The temperature errors, valued by their serial text (core/language.h STR_T_*)."""

    THERMAL_RUNAWAY = "Thermal Runaway"
    HEATING_FAILED = "Heating failed"
    MAXTEMP = "MAXTEMP triggered"
    MINTEMP = "MINTEMP triggered"


# The LCD message each error passes to kill() (lcd/language/language_en.h, English).
_LCD_TEXT = {
    TempError.THERMAL_RUNAWAY: "THERMAL RUNAWAY",  # MSG_THERMAL_RUNAWAY
    TempError.HEATING_FAILED: "Heating Failed",  # MSG_HEATING_FAILED_LCD
    TempError.MAXTEMP: "Err: MAXTEMP",  # MSG_ERR_MAXTEMP
    TempError.MINTEMP: "Err: MINTEMP",  # MSG_ERR_MINTEMP
}
M112_KILL_STR = "M112 Shutdown"  # MarlinCore.cpp
STR_ERR_KILLED = "Printer halted. kill() called!"


def _check_version(version: str) -> None:
    if version not in VERSIONS:
        raise ValueError(f"unknown Marlin version {version!r}; expected one of {VERSIONS}")


def kill_text(lcd_msg: str | None, *, version: str = DEFAULT_VERSION) -> str:
    """What kill() prints on a board with no display, before minkill() halts it silently.

    2.1.x echoes the LCD message to serial whether or not a display exists; 2.0.x (before
    2.0.9) printed only the halted line. ACTION_ON_KILL is off by default, so no //action:kill.
    """
    _check_version(version)
    echo = f"echo:{lcd_msg}\n" if lcd_msg is not None and version == MarlinVersion.V2_1 else ""
    return f"{echo}Error:{STR_ERR_KILLED}\n"


def temp_error_text(kind: TempError | str, heater_id: int, *, version: str = DEFAULT_VERSION) -> str:
    """The serial text of _temp_error then loud_kill -> kill, for hotend heater_id >= 0 or H_BED.

    2.1.x names a hotend `E<n>` with SERIAL_ECHOLNPGM and then adds SERIAL_EOL, so a blank
    line follows; 2.0.x printed the bare number.
    """
    _check_version(version)
    kind = TempError(kind)
    if heater_id == H_BED:
        heater = "bed\n"
    elif heater_id < 0:
        raise ValueError(f"heater_id must be a hotend index >= 0 or H_BED, not {heater_id}")
    elif version == MarlinVersion.V2_1:
        heater = f"E{heater_id}\n\n"
    else:
        heater = f"{heater_id}\n"
    error = f"Error:{kind.value}, system stopped! Heater_ID: {heater}"
    return error + kill_text(_LCD_TEXT[kind], version=version)


def m112_text(*, version: str = DEFAULT_VERSION) -> str:
    """M112 (emergency stop): kill(M112_KILL_STR)."""
    return kill_text(M112_KILL_STR, version=version)
