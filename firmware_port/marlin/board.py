"""The ATmega328 board: the temperature ISR and Marlin's ``Temperature::task()`` around it.

Only pins cross the boundary: the board pulls 10-bit ADC samples from an ``AdcPort`` when its
ADC state machine samples a channel, and exposes the heater pin levels, which change only
inside ``isr()``. ``task()`` is Marlin's main loop: it converts fresh raw readings, runs the
MIN/MAXTEMP checks, and runs each heater's controller and protection on fresh readings only
(every 160 ISRs = 0.16384 s). The caller drives the clock: ``isr()`` at 976.5625 Hz and
``task()`` in between (``step()`` does both).
"""

from __future__ import annotations

from typing import Protocol

from firmware_port.controller import BoardInputs, Controller, ReadsBoard, is_tunable
from firmware_port.marlin.adc import AdcPort, AdcSequencer
from firmware_port.marlin.autotune import Autotune
from firmware_port.marlin.constants import ms_to_ticks, ticks_to_ms
from firmware_port.marlin.pid import BED_GAINS, PidFixed, PidGains
from firmware_port.marlin.protection import (
    H_BED,
    HeaterWatch,
    RunawayMonitor,
    TempError,
    TempRange,
    heater_on,
    m112_text,
    temp_error_text,
    time_pending,
)
from firmware_port.marlin.serial import Console, format_float
from firmware_port.marlin.softpwm import SoftPwm
from firmware_port.marlin.versions import DEFAULT_VERSION, MarlinVersion
from firmware_port.thermistor import B3950_TABLE, TEMP_ONE, TempTable

HOTEND_CHANNEL = 0
BED_CHANNEL = 1


class BoardTune(Protocol):
    """A blocking loop that takes over Marlin's main loop until ``done`` (M303, M306 T): one
    pass per ``poll``; the board drives the tuned heater's soft PWM from ``amount``."""

    amount: int  # the tuned heater's soft_pwm_amount, 0..127
    done: bool
    succeeded: bool
    gains: tuple[float, float, float] | None  # PID gains M303 U1 applies (None: nothing to apply)

    def poll(self, now_ms: int, temp_q5: int | None) -> None: ...

    def next_deadline_ms(self) -> int: ...

    def cancel(self) -> None: ...


class Heater:
    """One heater: sensor channel + controller + soft-PWM slot + protection state."""

    def __init__(self, heater_id: int, controller: Controller, table: TempTable, temp_range: TempRange, runaway, watch):
        self.heater_id = heater_id  # 0 = hotend E0, H_BED = -1
        self.controller = controller
        self.table = table
        self.temp_range = temp_range
        self.runaway = runaway
        self.watch = watch
        self.target_c = 0  # celsius_t, int16
        self.raw = 0  # uint16, last raw ADC sum
        self.temp_q5 = 0  # celsius_q5, int16
        self.next_check_ms = 0  # gate for controllers that run every check_interval_ms

    @property
    def is_bed(self) -> bool:
        return self.heater_id == H_BED

    def __repr__(self) -> str:
        return f"Heater({'bed' if self.is_bed else f'E{self.heater_id}'}, target={self.target_c}, " \
               f"temp={self.temp_q5 / TEMP_ONE:.2f}, controller={self.controller!r})"


class MarlinBoard:
    """A Marlin 2.1 board with a hotend (channel 0) and optionally a bed (channel 1)."""

    def __init__(
        self,
        adc_port: AdcPort,
        hotend_controller: Controller | None = None,
        bed_controller: Controller | None = None,
        *,
        has_bed: bool = True,
        hotend_table: TempTable = B3950_TABLE,
        bed_table: TempTable = B3950_TABLE,
        console: Console | None = None,
        version: str = DEFAULT_VERSION,
        thermal_protection: bool = True,
    ):
        self.console = console if console is not None else Console()
        self.version = version
        # THERMAL_PROTECTION_HOTENDS / _BED: the runaway monitor and the heating watch (WATCH_TEMP_*),
        # both off when False (a sketch without them, seed 004's); MINTEMP and MAXTEMP stay.
        self.thermal_protection = thermal_protection
        hotend = Heater(
            0,
            hotend_controller if hotend_controller is not None else PidFixed(),
            hotend_table,
            TempRange.hotend(hotend_table),
            RunawayMonitor.hotend(),
            HeaterWatch.hotend(),
        )
        self.heaters = [hotend]
        if has_bed:
            bed = Heater(
                H_BED,
                bed_controller if bed_controller is not None else PidFixed(BED_GAINS),
                bed_table,
                TempRange.bed(bed_table),
                RunawayMonitor.bed(),
                HeaterWatch.bed(),
            )
            self.heaters.append(bed)
        # Configuration.h's DEFAULT_Kp... of this build (what M502 restores): the gains its controllers came with
        self.default_gains = [heater.controller.gains if is_tunable(heater.controller) else None  # type: ignore[attr-defined]
                              for heater in self.heaters]
        self.adc = AdcSequencer(len(self.heaters), adc_port)
        self.pwm = SoftPwm(len(self.heaters))
        self.ticks = 0  # ISRs run since reset
        self.halted = False
        self.fan_speed = 0  # part fan 0..255 (M106), driven by hardware PWM
        self.e_position_steps = 0  # stepper.position(E_AXIS), int32: the world moves it as filament feeds
        self.autotune: BoardTune | None = None  # M303 or M306 T in progress
        self.autotune_channel = HOTEND_CHANNEL
        self.autotune_apply = False  # M303 U1

    def __repr__(self) -> str:
        controllers = ", ".join(f"{'bed' if h.is_bed else 'hotend'} {type(h.controller).__name__}" for h in self.heaters)
        return f"MarlinBoard(Marlin {self.version}, {controllers}, ms={self.now_ms}{', halted' if self.halted else ''})"

    # -- the outside world's view -------------------------------------------------------
    @property
    def now_ms(self) -> int:
        """millis()."""
        return ticks_to_ms(self.ticks)

    @property
    def hotend(self) -> Heater:
        return self.heaters[HOTEND_CHANNEL]

    @property
    def bed(self) -> Heater | None:
        return self.heaters[BED_CHANNEL] if len(self.heaters) > 1 else None

    def pin(self, channel: int) -> bool:
        """Heater output pin level."""
        return self.pwm.pins[channel]

    def amount(self, channel: int) -> int:
        """soft_pwm_amount, 0..127 (what M105 prints after @:); M303 writes it directly."""
        if self.autotune is not None and channel == self.autotune_channel:
            return self.autotune.amount
        return self.pwm.amount[channel]

    # -- the clock ------------------------------------------------------------------------
    def isr(self) -> None:
        """One temperature ISR (Timer0 compare A): soft PWM, then the ADC state machine."""
        if self.halted:  # minkill(): interrupts off for good
            return
        self.pwm.tick()
        self.adc.tick()
        self.ticks += 1

    def task(self) -> None:
        """Temperature::task(): act on a fresh reading, if there is one.

        While M303 or M306 T runs, Marlin's main loop is its autotune loop instead: it polls every pass,
        converts fresh readings (with the raw MIN/MAXTEMP checks) and runs no other control.
        """
        if self.halted:
            return
        fresh = self.adc.raw_ready
        if fresh:
            self._update_temperatures()
            if self.halted:
                return
        if self.autotune is not None:
            return self._run_autotune(fresh)
        if not fresh:
            return
        now_ms = self.now_ms
        self._manage_hotend(self.hotend, now_ms)
        if not self.halted and self.bed is not None:
            self._manage_bed(self.bed, now_ms)

    def step(self) -> None:
        """One ISR followed by the main loop."""
        self.isr()
        self.task()

    def skip(self, n_ticks: int, samples) -> None:
        """``n_ticks`` ISRs at once (no main loop in between), given each channel's ADC
        conversions at ``adc.sample_offsets(n_ticks)``; the caller keeps ``n_ticks`` within
        ``ticks_to_task()`` so no main-loop pass is missed."""
        if self.halted:
            return
        self.pwm.skip(n_ticks)
        self.adc.skip(n_ticks, samples)
        self.ticks += n_ticks

    def ticks_to_task(self) -> int:
        """ISRs until the main loop next has something to do: a fresh reading, or an M303 deadline."""
        n_ticks = self.adc.ticks_to_reading()
        if self.autotune is not None:
            deadline_tick = ms_to_ticks(self.autotune.next_deadline_ms())
            n_ticks = min(n_ticks, max(1, deadline_tick - self.ticks))
        return n_ticks

    # -- commands (what G-code handlers call) ---------------------------------------------
    def set_target(self, channel: int, target_c: int) -> None:
        """setTargetHotend / setTargetBed: clamp to maxtemp - overshoot and restart the watch."""
        heater = self.heaters[channel]
        heater.target_c = heater.temp_range.clamp_target(target_c)
        heater.watch.restart(heater.temp_q5, heater.target_c, self.now_ms)

    def disable_all_heaters(self) -> None:
        """Targets to 0, amounts to 0, pins low at once."""
        for channel in range(len(self.heaters)):
            self.set_target(channel, 0)
        self.pwm.all_off()

    def temp_c(self, channel: int) -> float:
        """The heater's current reading in degC (celsius_q5 / 32), as M105 prints it."""
        return self.heaters[channel].temp_q5 / TEMP_ONE

    def target_c(self, channel: int) -> int:
        return self.heaters[channel].target_c

    def has_gains(self, channel: int) -> bool:
        """PIDTEMP (hotend) / PIDTEMPBED (bed): the heater's controller takes PID gains."""
        return channel < len(self.heaters) and is_tunable(self.heaters[channel].controller)

    def gains(self, channel: int) -> PidGains:
        """The heater's PID gains (M301/M304); ValueError if its controller has none."""
        self._check_gains(channel)
        return self.heaters[channel].controller.gains  # type: ignore[attr-defined]

    def set_gains(self, channel: int, gains: PidGains) -> None:
        """M301/M304: new gains (the controller resets its loop)."""
        self._check_gains(channel)
        self.heaters[channel].controller.set_gains(gains)  # type: ignore[attr-defined]

    def _check_gains(self, channel: int) -> None:
        if not self.has_gains(channel):
            controller = type(self.heaters[channel].controller).__name__ if channel < len(self.heaters) else None
            raise ValueError(f"heater {channel} has no PID gains (controller {controller})")

    def can_autotune(self, channel: int) -> bool:
        """M303 needs PIDTEMP (hotend) or PIDTEMPBED (bed): a controller with PID gains."""
        return self.has_gains(channel)

    def start_autotune(self, channel: int, target_c: int, ncycles: int, apply: bool = False,
                       version: str = DEFAULT_VERSION) -> Autotune:
        """M303: Marlin's relay autotune on one heater; the board runs it until it is done."""
        heater = self.heaters[channel]
        tune = Autotune(
            heater.heater_id,
            target_c,
            ncycles,
            heater.is_bed,
            self.console,
            self.heater_states,
            lambda kind: self.temp_error(heater, TempError(kind)),
            heater.temp_range.maxtemp_c,
            version,
        )
        tune.start(self.now_ms)
        if tune.done:  # refused before disable_all_heaters()
            return tune
        self.disable_all_heaters()
        self.begin_tune(tune, channel, apply)
        return tune

    def begin_tune(self, tune: BoardTune, channel: int, apply: bool = False) -> None:
        """Hand the main loop to a started tune on ``channel`` until it is done (``apply``: M303 U1)."""
        self.autotune, self.autotune_channel, self.autotune_apply = tune, channel, apply
        self.pwm.set_amount(channel, tune.amount)

    def cancel_autotune(self) -> None:
        """M108 during M303 or M306 T: the loop ends and the heaters go off."""
        if self.autotune is not None:
            self.autotune.cancel()
            self._end_autotune()

    def _run_autotune(self, fresh: bool) -> None:
        tune, channel = self.autotune, self.autotune_channel
        assert tune is not None  # task() runs this only during M303
        tune.poll(self.now_ms, self.heaters[channel].temp_q5 if fresh else None)
        if self.halted:  # a temperature error inside M303 killed the board
            self.autotune = None
            return
        self.pwm.set_amount(channel, tune.amount)
        if tune.done:
            if tune.succeeded and self.autotune_apply and tune.gains is not None:
                self.set_gains(channel, PidGains.clamped(*tune.gains))
            self._end_autotune()

    def _end_autotune(self) -> None:
        if self.autotune is not None:
            self.pwm.set_amount(self.autotune_channel, self.autotune.amount)
        self.autotune = None

    def kill_m112(self) -> None:
        """M112: kill(M112_KILL_STR) and halt."""
        self.disable_all_heaters()
        self.console.write(m112_text(version=self.version))
        self.halted = True

    def heater_states(self) -> str:
        """print_heater_states(): `` T:cur /target B:cur /target @:amount B@:amount``."""
        text = ""
        for heater in self.heaters:
            letter = "B" if heater.is_bed else "T"
            text += f" {letter}:{format_float(heater.temp_q5 / TEMP_ONE)} /{format_float(heater.target_c)}"
        text += f" @:{self.amount(HOTEND_CHANNEL)}"
        if self.bed is not None:
            text += f" B@:{self.amount(BED_CHANNEL)}"
        return text

    # -- Marlin's temperature.cpp ---------------------------------------------------------
    def temp_error(self, heater: Heater, kind: TempError) -> None:
        """_temp_error(): print the error, disable all heaters, kill() and halt."""
        self.disable_all_heaters()
        self.console.write(temp_error_text(kind, heater.heater_id, version=self.version))
        self.halted = True

    def _update_temperatures(self) -> None:
        """updateTemperaturesFromRawValues(): convert, then the raw MAXTEMP/MINTEMP checks."""
        for channel, heater in enumerate(self.heaters):
            heater.raw = self.adc.raw[channel]
            heater.temp_q5 = heater.table.lookup_q5(heater.raw)
        self.adc.raw_ready = False
        for channel, heater in enumerate(self.heaters):
            if heater.temp_range.maxtemp_raw_tripped(heater.raw):
                return self.temp_error(heater, TempError.MAXTEMP)
            on = heater_on(heater.target_c, self.amount(channel), version=self._heater_on_version(heater))
            if heater.temp_range.mintemp_raw_tripped(heater.raw, on):
                return self.temp_error(heater, TempError.MINTEMP)

    def _heater_on_version(self, heater: Heater) -> str:
        """The bed's MINTEMP looks at the target only, in every version."""
        return MarlinVersion.V2_1 if heater.is_bed else self.version

    def controller_output(self, channel: int, now_ms: int) -> int:
        """get_pid_output_hotend() / _bed(): the heater's controller on its latest reading, 0..255.
        A controller that reads the board (Marlin's MPC) is first given what it reads."""
        heater = self.heaters[channel]
        if isinstance(heater.controller, ReadsBoard):
            heater.controller.read_board(BoardInputs(self.amount(channel), self.fan_speed, self.e_position_steps))
        return heater.controller.update(heater.temp_q5, heater.target_c, now_ms)

    def _manage_hotend(self, heater: Heater, now_ms: int) -> None:
        """manage_hotends(): MAXTEMP, runaway, the controller, then the heating watch."""
        temp_q5 = heater.temp_q5
        if heater.temp_range.maxtemp_tripped(temp_q5):
            return self.temp_error(heater, TempError.MAXTEMP)
        if self.thermal_protection and heater.runaway.run(temp_q5, heater.target_c, now_ms):
            return self.temp_error(heater, TempError.THERMAL_RUNAWAY)
        in_range = heater.temp_range.mintemp_c * TEMP_ONE < temp_q5 < heater.temp_range.maxtemp_c * TEMP_ONE
        amount = self.controller_output(HOTEND_CHANNEL, now_ms) >> 1 if in_range else 0
        self.pwm.set_amount(HOTEND_CHANNEL, amount)
        if self.thermal_protection and heater.watch.heating_failed(temp_q5, heater.target_c, now_ms):
            self.temp_error(heater, TempError.HEATING_FAILED)

    def _manage_bed(self, heater: Heater, now_ms: int) -> None:
        """manage_heated_bed(): MAXTEMP, watch, then (bang-bang: every 5 s) runaway and control."""
        temp_q5 = heater.temp_q5
        if heater.temp_range.maxtemp_tripped(temp_q5):
            return self.temp_error(heater, TempError.MAXTEMP)
        if self.thermal_protection and heater.watch.heating_failed(temp_q5, heater.target_c, now_ms):
            return self.temp_error(heater, TempError.HEATING_FAILED)
        interval_ms = heater.controller.check_interval_ms
        if interval_ms is not None:
            if time_pending(now_ms, heater.next_check_ms):
                return
            heater.next_check_ms = now_ms + interval_ms
        if self.thermal_protection and heater.runaway.run(temp_q5, heater.target_c, now_ms):
            return self.temp_error(heater, TempError.THERMAL_RUNAWAY)
        limits = heater.temp_range
        if limits.mintemp_c * TEMP_ONE <= temp_q5 <= limits.maxtemp_c * TEMP_ONE:
            self.pwm.set_amount(BED_CHANNEL, self.controller_output(BED_CHANNEL, now_ms) >> 1)
        else:
            self.pwm.set_amount(BED_CHANNEL, 0)
            self.pwm.pins[BED_CHANNEL] = False  # WRITE_HEATER_BED(LOW)
