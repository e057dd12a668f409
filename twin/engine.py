"""The lockstep engine: the firmware's board and the heaters' plants on one clock of ISR ticks.

Tick k is the k-th temperature ISR, at k x 1.024 ms. During tick k the ISR runs (it may take an
ADC sample of the sensor node as it is at that instant, and it sets the heater pins), then the
main loop, then the plant integrates over the tick with the pins as they are now. Nothing reads
the wall clock; same scenario and seed, same trace, bit for bit.

Two engines drive the same state:
- ``reference``: tick by tick, calling ``isr()`` and ``task()`` exactly as the MCU would. The
  oracle.
- ``fast``: between two main-loop actions (a fresh reading, an M303 deadline) and scenario
  events the firmware's inputs are known in advance: the pin waveforms follow from the latched
  soft-PWM amounts, the ADC samples the sensor at fixed ISR phases. So a whole control period
  is one linear map per plant and one bulk ADC conversion, and the board skips its ISRs in
  closed form. It feeds the firmware the same samples as the reference engine (tested).

``avr`` is the fast engine with each heater's controller replaced by its AVR build, the compiled
C law stepped in simavr (firmware_port/avr/controllers.py); its trace equals the fast engine's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from firmware_port.controller import Controller, ControllerSpec, Observable
from firmware_port.firmwares import build_controllers
from firmware_port.fixed import wrap_s32
from firmware_port.marlin.board import BED_CHANNEL, HOTEND_CHANNEL, MarlinBoard
from firmware_port.marlin.constants import E_STEPS_PER_MM, TICKS_PER_READING
from firmware_port.marlin.pid import PidGains
from firmware_port.marlin.serial import Console
from firmware_port.thermistor import TEMP_ONE
from twin.clock import TICK_S, EventQueue, ticks_at
from twin.limits import DURATION_MAX_S, PHYSICAL_RANGE_C, TARGET_RANGE_C, check_trace_bytes, checked, checked_seed
from twin.linear import BLOCK, SENSOR
from twin.result import HEATERS, RunResult
from twin.sensor import SensorChain, seeded_chains
from twin.trace import Trace

ENGINES = ("fast", "reference", "avr")  # avr: the fast engine with the controllers' compiled C in simavr
HALTED_RUN_TICKS = 160  # record cadence while the board is dead
NORMAL, DISCONNECTED, STUCK_ON = "normal", "heater_disconnected", "heater_stuck_on"
HEATER_NAMES = ("hotend", "bed")  # by channel
BOOT_S = 2.0  # Twin.create: the board runs this long before time 0
# A trace row's memory: about 400 bytes for a hotend, 560 with a bed, a PID's terms included (tracemalloc
# over 600 s of heat_hold); the bound that refuses a run whose trace would not fit in memory.
TRACE_ROW_BYTES = 600


class HeaterHandle:
    """One heater of a twin, as a user sees it: ``target_c``, ``gains``, ``temp_c``."""

    def __init__(self, twin: Twin, channel: int):
        self._twin, self.channel = twin, channel

    @property
    def target_c(self) -> int:
        return self._twin.board.target_c(self.channel)

    @target_c.setter
    def target_c(self, value: float) -> None:
        """M104/M140 S<value>: the firmware clamps to its maximum as Marlin does."""
        self._twin.board.set_target(self.channel, int(checked("target_c", value, *TARGET_RANGE_C, "C")))

    @property
    def gains(self) -> PidGains:
        """PID gains in user units (M301/M304); ValueError for a controller without gains."""
        return self._twin.board.gains(self.channel)

    @gains.setter
    def gains(self, gains: PidGains) -> None:
        self._twin.board.set_gains(self.channel, gains)

    @property
    def temp_c(self) -> float:
        """What the firmware reads now (degC)."""
        return self._twin.board.temp_c(self.channel)

    @property
    def true_c(self) -> float:
        """The plant's sensor-node temperature now (degC)."""
        return float(self._twin.plants[self.channel].temps_c()[SENSOR])

    @property
    def duty(self) -> float:
        """Soft-PWM amount / 127."""
        return self._twin.board.amount(self.channel) / 127

    @property
    def controller(self) -> Controller:
        return self._twin.board.heaters[self.channel].controller


class Twin:
    """A board running a firmware build, a plant and a sensor chain per heater, and a trace."""

    def __init__(
        self,
        plants: list,
        firmware: str = "pid",
        *,
        controllers: Sequence[ControllerSpec | None] = (),
        sensors: list[SensorChain] | None = None,
        seed: int = 0,
        noise_lsb: float = 0.0,
        engine: str = "fast",
        board_options: dict | None = None,
    ):
        if engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, not {engine!r}")
        self.engine = engine
        self.plants = plants
        self.sensors = seeded_chains(len(plants), checked_seed("seed", seed), noise_lsb) if sensors is None else sensors
        self.firmware = firmware
        if len(controllers) > len(plants):
            raise ValueError(f"{len(controllers)} controllers for {len(plants)} heaters")
        self.controllers = tuple(controllers)  # per channel: instance, factory or None (the firmware's)
        self.board_options = board_options or {}
        self.console = Console()
        self.tick = 0
        self._flow_mm_s = 0.0  # filament feed now (mm/s): the plant's input, and what moves the E stepper
        self._fed_mm, self._fed_tick = 0.0, 0  # filament fed since the board's reset, up to _fed_tick
        self.reset_board()
        self.origin_tick = 0  # scenario time 0 (after boot)
        self.ambient_c = float(plants[0].d[0])
        self.heater_mode = [NORMAL] * len(plants)
        self.fan_failed = False
        self._applied_inputs: tuple[float, float, float] | None = None
        self.trace = Trace()
        self.recording = True  # trace rows and events (a serial session turns it off)
        # A row per firmware reading (0.16384 s, about 8.5 MB per virtual hour with a bed) unless
        # set: then at most one row per record_every_s; events are always kept.
        self.record_every_s = 0.0
        self.console.listeners.append(self._console_to_trace)
        self._partial_line = ""
        self._task_tick: int | None = None  # while the main loop runs: the tick it runs at
        self._events = EventQueue()  # actions due at a tick

    @classmethod
    def create(cls, firmware: str = "pid", hotend: str | None = None, bed: str | None = None, *,
               controllers: Sequence[ControllerSpec | None] = (), ambient_c: float = 25.0,
               boot_s: float = BOOT_S, **options) -> Twin:
        """A twin on plant presets (twin.plants.PRESETS; the hotend by default twin.plants.DEFAULT_HOTEND,
        no bed unless named), booted so that time 0 is a running board."""
        from twin.plants import DEFAULT_HOTEND, make_plant

        checked("boot_s", boot_s, 0.0, DURATION_MAX_S, "s")
        plants = [make_plant(hotend or DEFAULT_HOTEND, ambient_c=ambient_c)]
        if bed is not None:
            plants.append(make_plant(bed, ambient_c=ambient_c))
        twin = cls(plants, firmware, controllers=controllers, **options)
        twin.boot(boot_s)
        return twin

    def reset_board(self) -> None:
        """Power-cycle or reset the MCU: a fresh board and firmware; the plants keep their heat.

        Injected controller instances survive (reset, with their gains, as if from EEPROM);
        factories are called again."""
        built = list(build_controllers(self.firmware))
        if self.engine == "avr":
            from firmware_port.avr.controllers import on_avr  # ctypes and the toolchain, only when asked

            built = [on_avr(controller) for controller in built]
        for channel, spec in enumerate(self.controllers):
            if spec is None:
                continue
            if isinstance(spec, Controller):
                spec.reset()
                built[channel] = spec
            else:
                built[channel] = spec()
        self.board = MarlinBoard(
            self, built[0], built[1], has_bed=len(self.plants) > 1, console=self.console, **self.board_options
        )
        self._fed_mm, self._fed_tick = 0.0, self.tick  # the stepper counts from 0 after a reset

    # -- the user's view --------------------------------------------------------------------
    @property
    def hotend(self) -> HeaterHandle:
        return HeaterHandle(self, HOTEND_CHANNEL)

    @property
    def bed(self) -> HeaterHandle:
        if len(self.plants) <= BED_CHANNEL:
            raise AttributeError("this twin has no bed")
        return HeaterHandle(self, BED_CHANNEL)

    def run(self, seconds: float) -> RunResult:
        """Run ``seconds`` more of virtual time; the result of everything recorded since time 0 (``result()``
        without running)."""
        checked("seconds", seconds, 0.0, DURATION_MAX_S - self.time_s, "s", above=True)
        self.run_until(self.time_s + seconds)
        return self.result()

    def result(self, label: str | None = None) -> RunResult:
        names = HEATER_NAMES[: len(self.plants)]
        if label is None:
            plants = ", ".join(f"{n} {getattr(p, 'preset', '?')}" for n, p in zip(names, self.plants))
            gains = "; ".join(f"{n} Kp {g.kp:g} Ki {g.ki:g} Kd {g.kd:g}" for c, n in enumerate(names)
                              if self.board.has_gains(c) for g in [self.board.gains(c)])
            label = f"{self.firmware}: {plants}" + (f" ({gains})" if gains else "")
        return self.trace.result(names, label)

    # -- the outside world ----------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Scenario time: seconds since the end of boot."""
        return (self.tick - self.origin_tick) * TICK_S

    def boot(self, seconds: float) -> None:
        """Power the board up ``seconds`` before scenario time 0, as a printer is on before the
        host talks to it (Marlin's first reading after reset sums 15 samples, not 16)."""
        self.run_until(seconds)
        self.origin_tick = self.tick
        self.trace = Trace()

    @property
    def flow_mm_s(self) -> float:
        """Filament feed into the hotend now, mm/s (negative: retraction)."""
        return self._flow_mm_s

    @flow_mm_s.setter
    def flow_mm_s(self, value: float) -> None:
        value = checked("flow_mm_s", value)
        if value != self._flow_mm_s:
            self._fed_mm, self._fed_tick = self._fed_at(self.tick), self.tick
            self._flow_mm_s = value

    def _fed_at(self, tick: int) -> float:
        return self._fed_mm + self._flow_mm_s * (tick - self._fed_tick) * TICK_S

    def _set_e_stepper(self, tick: int) -> None:
        """The E stepper's position when the main loop runs at ``tick``: the whole steps fed."""
        self.board.e_position_steps = wrap_s32(math.floor(self._fed_at(tick) * E_STEPS_PER_MM))

    @property
    def fan(self) -> float:
        """Part-fan speed the plant sees, 0..1 (the board's M106 value unless the fan failed)."""
        return 0.0 if self.fan_failed else self.board.fan_speed / 255

    def schedule(self, at_s: float, action: Callable[[Twin], None]) -> None:
        """Run ``action(twin)`` at the first tick at or after ``at_s`` (before that tick's ISR)."""
        self._events.push(self.origin_tick + ticks_at(checked("at_s", at_s, -DURATION_MAX_S, DURATION_MAX_S, "s")),
                          action, self)

    def set_heater_mode(self, channel: int, mode: str) -> None:
        """Heater wiring faults: normal, heater_disconnected (no power), heater_stuck_on (MOSFET shorted)."""
        if mode not in (NORMAL, DISCONNECTED, STUCK_ON):
            raise ValueError(f"not a heater mode: {mode!r}")
        self.heater_mode[channel] = mode

    def set_thermistor_fault(self, channel: int, fault: str | None) -> None:
        sensor_c = float(self.plants[channel].temps_c()[SENSOR])
        self.sensors[channel].set_fault(fault, self.tick, sensor_c, self.ambient_c)

    def set_ambient(self, ambient_c: float) -> None:
        self.ambient_c = checked("ambient_c", ambient_c, *PHYSICAL_RANGE_C, "C", above=True)
        for sensor in self.sensors:
            sensor.set_ambient(self.ambient_c, self.tick)

    # -- AdcPort (reference engine) -----------------------------------------------------------
    def sample(self, channel: int) -> int:
        """The ISR samples a sensor node now."""
        sensor_c = self.plants[channel].outputs(np.zeros(0), (0,))[:, SENSOR]
        return self.sensors[channel].samples(sensor_c, np.array([self.tick]))[0]

    # -- running ----------------------------------------------------------------------------
    def run_until(self, t_s: float) -> None:
        """Advance the clock to scenario time ``t_s`` seconds (at most DURATION_MAX_S, when Marlin's millis()
        wraps; ValueError if the trace would outgrow memory)."""
        self.check_horizon(t_s)
        self.run_ticks(self.origin_tick + ticks_at(t_s) - self.tick)

    def check_horizon(self, t_s: float) -> None:
        """ValueError unless a run to scenario time ``t_s`` is possible: finite, before Marlin's millis()
        wraps, and with a trace that fits in memory (a row per reading, or per ``record_every_s``)."""
        checked("t_s", t_s, -DURATION_MAX_S, DURATION_MAX_S, "s")
        every_s = checked("record_every_s", self.record_every_s, 0.0, DURATION_MAX_S, "s")
        if not self.recording:
            return
        rows = len(self.trace.rows) + max(0.0, t_s - self.time_s) / max(every_s, TICKS_PER_READING * TICK_S)
        check_trace_bytes(t_s, rows * TRACE_ROW_BYTES,
                          "record fewer rows (record_every_s, twin-sim --record-every) or run shorter")

    def run_ticks(self, n_ticks: int) -> None:
        """Advance the clock by ``n_ticks``, applying scheduled events on their ticks."""
        end = self.tick + n_ticks
        while self.tick < end:
            self._apply_due_events()
            due = self._events.next_at()
            stop = end if due is None else min(end, due)
            if stop <= self.tick:
                continue
            if self.engine == "reference":
                self._run_reference(stop - self.tick)
            else:
                self._run_fast(stop - self.tick)
        self._apply_due_events()

    def _apply_due_events(self) -> None:
        for _, action, args in self._events.pop_due(self.tick):
            action(*args)

    def _update_plant_inputs(self) -> None:
        inputs = (self.fan, self.flow_mm_s, self.ambient_c)
        if inputs != self._applied_inputs:
            for channel, plant in enumerate(self.plants):
                plant.set_inputs(fan=self.fan, flow_mm_s=self.flow_mm_s if channel == HOTEND_CHANNEL else 0.0,
                                 ambient_c=self.ambient_c)
            self._applied_inputs = inputs
        for plant in self.plants:
            plant.relinearise()

    def _heater_input(self, channel: int, pins: np.ndarray) -> np.ndarray:
        """Fraction of full power over each tick, given the pin levels."""
        mode = self.heater_mode[channel]
        if mode == DISCONNECTED:
            return np.zeros(len(pins))
        if mode == STUCK_ON:
            return np.ones(len(pins))
        return pins.astype(float)

    def _run_reference(self, n_ticks: int) -> None:
        board = self.board
        for _ in range(n_ticks):
            self._update_plant_inputs()
            board.isr()
            reading = board.adc.raw_ready and not board.halted
            self._task_tick = self.tick + 1
            self._set_e_stepper(self._task_tick)
            board.task()
            self._task_tick = None
            for channel, plant in enumerate(self.plants):
                plant.advance(self._heater_input(channel, np.array([board.pin(channel)])))
            self.tick += 1
            if reading or (board.halted and (self.tick - self.origin_tick) % HALTED_RUN_TICKS == 0):
                self._record()

    def _run_fast(self, n_ticks: int) -> None:
        board = self.board
        while n_ticks > 0:
            self._update_plant_inputs()
            if board.halted:
                since = (self.tick - self.origin_tick) % HALTED_RUN_TICKS
                n = min(n_ticks, HALTED_RUN_TICKS - since)
                for channel, plant in enumerate(self.plants):
                    plant.advance(self._heater_input(channel, np.zeros(n, bool)))
                self.tick += n
                if since + n == HALTED_RUN_TICKS:
                    self._record()
            else:
                n = min(n_ticks, board.ticks_to_task())
                self._fast_period(n)
            n_ticks -= n

    def _fast_period(self, n: int) -> None:
        """n ISRs in closed form, the main loop once, then the plants over the n ticks."""
        board = self.board
        offsets = board.adc.sample_offsets(n)
        inputs, samples = [], []
        for channel, plant in enumerate(self.plants):
            u = self._heater_input(channel, board.pwm.waveform(channel, n))
            offs = tuple(offsets[channel])
            sensor_c = plant.outputs(u, offs)[:, SENSOR] if offs else np.zeros(0)
            samples.append(self.sensors[channel].samples(sensor_c, self.tick + np.array(offs, dtype=int)))
            inputs.append(u)
        board.skip(n, samples)
        reading = board.adc.raw_ready
        self._task_tick = self.tick + n
        self._set_e_stepper(self._task_tick)
        board.task()
        self._task_tick = None
        for channel, plant in enumerate(self.plants):
            u = inputs[channel]
            u[-1] = self._heater_input(channel, np.array([board.pin(channel)]))[0]  # the main loop may have written the pin
            plant.advance(u)
        self.tick += n
        if reading:
            self._record()

    # -- recording --------------------------------------------------------------------------
    def _record(self) -> None:
        if not self.recording:
            return
        rows = self.trace.rows
        if self.record_every_s and rows and self.time_s - rows[-1][0] < self.record_every_s:
            return
        row = [self.time_s]
        for channel in (HOTEND_CHANNEL, BED_CHANNEL):
            if channel < len(self.plants):
                heater = self.board.heaters[channel]
                temps_c = self.plants[channel].temps_c()
                row += [heater.target_c, heater.temp_q5 / TEMP_ONE, float(temps_c[BLOCK]), float(temps_c[SENSOR]),
                        self.board.amount(channel) / 127]
            else:
                row += [0, 0.0, 0.0, 0.0, 0.0]
        row.append(self.fan)
        self.trace.append(tuple(row))
        for channel, name in enumerate(HEATERS[:len(self.plants)]):
            controller = self.board.heaters[channel].controller
            if isinstance(controller, Observable):
                self.trace.add_signals(name, controller.signals())

    def _console_to_trace(self, text: str) -> None:
        if not self.recording:
            return
        *complete, self._partial_line = (self._partial_line + text).split("\n")
        for line in complete:
            tick = self.tick if self._task_tick is None else self._task_tick
            self.trace.add_event((tick - self.origin_tick) * TICK_S, line)

