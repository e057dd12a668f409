"""The printer behind the twin MCU's pins: the twin's plants, thermistor chains and scenario faults.

Time is the world's MCU clock: the chip's ``clock_freq`` ticks per second since the twin started,
which a board reset does not restart (the hotend keeps its heat while the MCU reboots). The plants
step on their own tick (1.024 ms: 16384 clocks of a 16 MHz AVR, 73728 of a 72 MHz STM32, exactly) and are advanced lazily, only as far as
an ADC sample needs: a pin change the MCU makes at a clock the plants have not reached yet is
therefore exact however late the wall clock delivered it. Each heater pin's input per plant tick
is its exact on-fraction (``PinWave``); a fan pin's duty sets the hotend plant's part fan.

The wiring is that of Klipper's config/generic-ramps.cfg (an ATmega2560 with a RAMPS shield):
hotend heater PB4 and thermistor PK5, bed PH5 and PK6, part fan PH6.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmware_port.thermistor import KLIPPER_SENSORS, Divider, SteinhartHart
from protocol.klipper_mcu.axes import Carriage, Switch
from protocol.klipper_mcu.chip_temperature import CHIP_ABOVE_AMBIENT_C, TEMPERATURE_PIN_NAME, chip_sensor
from protocol.klipper_mcu.dictionary import BOARD_CHIP, DEFAULT_SENSOR, Chip
from protocol.klipper_mcu.probe import Probe
from protocol.klipper_mcu.user_config import ConfigError, ThermistorSpec, UserConfig
from twin.clock import TICK_S, EventQueue
from twin.engine import DISCONNECTED, NORMAL, STUCK_ON
from twin.linear import SENSOR
from twin.plants import Plant, make_plant
from twin.scenario import Event, Scenario
from twin.sensor import DETACHED, OPEN, SHORT, SensorChain



def tick_clocks(chip: Chip) -> int:
    """The chip's MCU clocks per plant tick (ValueError: not a whole number of them)."""
    clocks = chip.clocks(TICK_S)
    if clocks != TICK_S * chip.clock_freq:
        raise ValueError(f"the {chip.name}'s {chip.clock_freq} Hz clock has no whole number of clocks per plant tick")
    return clocks


TICK_CLOCKS = tick_clocks(BOARD_CHIP)  # 16384: the heater-only board's
RUN_TICKS = 1024  # the longest plant run: an idle MCU (no ADC query) is caught up in such runs
PULLUP_OHM = 4700.0  # klippy/extras/thermistor.py default pullup_resistor
DEFAULT_PLANTS = {"hotend": "hotend_stock", "bed": "bed"}  # twin/plants.py DEFAULT_HOTEND, DEFAULT_BED


@dataclass(frozen=True)
class Wiring:
    """Where one heater hangs on the MCU, and what its printer.cfg section says about it."""

    heater: str  # the scenario's name: "hotend" or "bed"
    heater_pin: str
    sensor_pin: str
    section: str  # printer.cfg section the config printer writes
    max_temp_c: float
    sensor_type: str | None = None  # None: the board's
    pullup_ohm: float = PULLUP_OHM


WIRING = (Wiring("hotend", "PB4", "PK5", "heater_generic hotend", 300.0),
          Wiring("bed", "PH5", "PK6", "heater_bed", 130.0))
FAN_PIN = "PH6"  # the part fan: acts on the hotend plant


class PinWave:
    """A pin's level over MCU clocks as the MCU drives it: from each change on, high for ``on`` of
    every ``period`` clocks (soft PWM restarts its cycle at each change, src/gpiocmds.c); a steady
    level is (0, 1) or (1, 1), a hardware PWM value v is (v, PWM_MAX)."""

    def __init__(self, tick_clocks: int) -> None:
        self.tick_clocks = tick_clocks
        self.starts = np.zeros(1, dtype=np.int64)
        self.on = np.zeros(1, dtype=np.int64)
        self.period = np.ones(1, dtype=np.int64)

    def __repr__(self) -> str:
        return f"PinWave({int(self.on[-1])}/{int(self.period[-1])} from clock {int(self.starts[-1])})"

    def drive(self, clock: int, on: int, period: int) -> None:
        """A change at ``clock`` (not before the last one: a late change takes effect at the last)."""
        clock = max(clock, int(self.starts[-1]))
        self.starts = np.append(self.starts, clock)
        self.on = np.append(self.on, min(on, period))
        self.period = np.append(self.period, period)

    def fractions(self, first_tick: int, n_ticks: int) -> np.ndarray:
        """The pin's on-fraction over each of n plant ticks from first_tick."""
        edges = (first_tick + np.arange(n_ticks + 1, dtype=np.int64)) * self.tick_clocks
        seg = np.maximum(np.searchsorted(self.starts, edges, side="right") - 1, 0)
        if seg[0] == seg[-1] and self.on[seg[0]] in (0, self.period[seg[0]]):
            return np.full(n_ticks, float(self.on[seg[0]] > 0))
        base = np.concatenate(([0], np.cumsum(_on_clocks(np.diff(self.starts), self.on[:-1], self.period[:-1]))))
        since = np.maximum(edges - self.starts[seg], 0)
        on_clocks = base[seg] + _on_clocks(since, self.on[seg], self.period[seg])
        return np.diff(on_clocks) / self.tick_clocks

    def duty(self) -> float:
        """The duty of the last change (what a fan's speed follows)."""
        return float(self.on[-1] / self.period[-1])

    def forget_before(self, clock: int) -> None:
        """Drop the changes that ended before ``clock``."""
        keep = max(int(np.searchsorted(self.starts, clock, side="right")) - 1, 0)
        self.starts, self.on, self.period = self.starts[keep:], self.on[keep:], self.period[keep:]


def _on_clocks(since: np.ndarray, on: np.ndarray, period: np.ndarray) -> np.ndarray:
    """High clocks within ``since`` clocks of a change: whole periods, then the part of the current one."""
    whole = since // period
    return whole * on + np.minimum(since - whole * period, on)


class _Heater:
    """One heater's plant, thermistor chain, pin and wiring fault."""

    def __init__(self, wiring: Wiring, plant: Plant, chain: SensorChain, tick_clocks: int):
        self.wiring, self.plant, self.chain = wiring, plant, chain
        self.pin = PinWave(tick_clocks)
        self.mode = NORMAL

    def heater_input(self, first_tick: int, n_ticks: int) -> np.ndarray:
        if self.mode == DISCONNECTED:
            return np.zeros(n_ticks)
        if self.mode == STUCK_ON:
            return np.ones(n_ticks)
        return self.pin.fractions(first_tick, n_ticks)


def _part(config: UserConfig, spec: ThermistorSpec) -> SteinhartHart:
    """A config's own thermistor as klippy computes it (ConfigError: points no curve passes through)."""
    try:
        if spec.beta is not None:
            (temp_c, ohm), = spec.points
            return SteinhartHart.from_beta(ohm, spec.beta, temp_c)
        return SteinhartHart.from_points(spec.points)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # a singular system, a log of 0 ohm
        raise ConfigError(f"{config.path}: [{spec.section}]: not a thermistor: {exc}") from None


class TwinBoard:
    """The twin's heaters behind the MCU's pins; the MCU calls ``adc`` and ``drive`` with world clocks."""

    def __init__(self, scenario: Scenario, heaters: tuple[str, ...] = ("hotend", "bed"),
                 sensor_type: str = DEFAULT_SENSOR, noise_lsb: float = 0.0, wirings: tuple[Wiring, ...] = WIRING,
                 fan_pin: str | None = FAN_PIN, chip: Chip = BOARD_CHIP,
                 thermistors: dict[str, SteinhartHart] | None = None):
        """The heaters named in ``heaters`` on their ``wirings`` (a printer.cfg's: ``for_config``), behind the
        ``chip``'s ADC and clock; ``thermistors``: the sensor types by name (Klipper's, and a config's own)."""
        self.thermistors = KLIPPER_SENSORS if thermistors is None else thermistors
        for wiring in wirings:
            if (wiring.sensor_type or sensor_type) not in self.thermistors:
                raise ValueError(f"unknown sensor_type {wiring.sensor_type or sensor_type!r}; valid: "
                                 f"{', '.join(self.thermistors)}")
        self.scenario, self.sensor_type, self.noise_lsb = scenario, sensor_type, noise_lsb
        self.ambient_c = scenario.ambient_c
        self.chip, self.tick_clocks = chip, tick_clocks(chip)
        wirings = tuple(w for w in wirings if w.heater in heaters)
        self.wirings, self.fan_pin = wirings, fan_pin
        streams = np.random.SeedSequence(scenario.seed or 0).spawn(len(wirings))
        self.heaters: dict[str, _Heater] = {}
        for wiring, stream in zip(wirings, streams):
            params = dict(scenario.plant.get(wiring.heater, {}))
            preset = str(params.pop("preset", DEFAULT_PLANTS[wiring.heater]))
            plant = make_plant(preset, ambient_c=scenario.ambient_c, initial_c=scenario.initial_c.get(wiring.heater),
                               **params)
            self.heaters[wiring.heater] = _Heater(wiring, plant, self._chain(wiring.sensor_type, wiring.pullup_ohm,
                                                                             stream), self.tick_clocks)
        self._by_pin = {h.wiring.heater_pin: h for h in self.heaters.values()}
        self._by_sensor = {h.wiring.sensor_pin: h for h in self.heaters.values()}
        self._ambient_sensors: dict[str, SensorChain] = {}  # thermistors no simulated heater warms
        self._carriages: dict[str, Carriage] = {}  # by step pin
        self._endstops: dict[str, tuple[Switch | Probe, int]] = {}  # by pin: its switch, the level when pressed
        self.probe: Probe | None = None  # a BLTouch's control pin drives it
        self.tick = 0  # the plants' state is at this plant tick
        self.fan = PinWave(self.tick_clocks)
        self.fan_failed = False
        self._actions = EventQueue()  # (plant tick, action): scenario events and fan changes
        for event in scenario.events:
            if event.kind not in ("target", "gains") and (event.heater is None or event.heater in self.heaters):
                self._actions.push(round(event.at_s / TICK_S), self._apply_event, event)

    @classmethod
    def for_config(cls, config: UserConfig, scenario: Scenario, noise_lsb: float = 0.0) -> TwinBoard:
        """The board a user's printer.cfg describes: its heaters, thermistors, fan and axes on their pins."""
        thermistors = {**KLIPPER_SENSORS, **{name: _part(config, spec) for name, spec in config.thermistors.items()}}
        for heater in config.heaters:
            if heater.sensor_type not in thermistors:
                raise ConfigError(f"{config.path}: [{heater.section}] sensor_type {heater.sensor_type!r}: the twin "
                                  f"simulates these thermistors: {', '.join(thermistors)}")
        wirings = tuple(Wiring(h.heater, h.heater_pin, h.sensor_pin, h.section, h.max_temp_c, h.sensor_type,
                               h.pullup_ohm) for h in config.heaters)
        board = cls(scenario, tuple(w.heater for w in wirings), noise_lsb=noise_lsb, wirings=wirings,
                    fan_pin=config.fan_pin, chip=config.chip, thermistors=thermistors)
        for sensor in config.sensors:
            if sensor.sensor_type in thermistors:  # others (a PT100 amplifier, a chip sensor) read open
                board._ambient_sensors[sensor.pin] = board._chain(sensor.sensor_type, sensor.pullup_ohm, None)
        rails = [axis.rail for axis in config.axes] + ([config.probe.z] if config.probe and config.probe.z else [])
        for rail in rails:
            for stepper, _ in rail.terms:
                board.carriage(stepper.step_pin).stepper = stepper
        for axis in config.axes:
            board._endstops[axis.endstop.name] = (Switch(axis, board.carriage), 1 ^ int(axis.endstop.inverted))
        if config.probe is not None:
            board.probe = Probe(config.probe, board.carriage)
            board._endstops[config.probe.sensor.name] = (board.probe, 1 ^ int(config.probe.sensor.inverted))
        return board

    def _chain(self, sensor_type: str | None, pullup_ohm: float, stream) -> SensorChain:
        divider = Divider(self.thermistors[sensor_type or self.sensor_type], pullup_ohm)
        chain = SensorChain(divider, noise_lsb=self.noise_lsb if stream is not None else 0.0,
                            rng=np.random.default_rng(stream), adc_counts=self.chip.adc_max + 1)
        chain.set_ambient(self.ambient_c, 0)
        return chain

    def carriage(self, step_pin: str) -> Carriage:
        """The carriage on a step pin (one with no endstop, an extruder's, is made on first use)."""
        return self._carriages.setdefault(step_pin, Carriage())

    def endstop(self, pin: str) -> tuple[Switch | Probe | None, int]:
        """The switch (or probe) on ``pin`` and the pin's level when pressed (none: a pin never pressed)."""
        return self._endstops.get(pin, (None, 1))

    # -- what the MCU does to the pins ---------------------------------------------------------
    def __repr__(self) -> str:
        return f"TwinBoard({', '.join(f'{name} {h.plant!r}' for name, h in self.heaters.items())}, {self.sensor_type})"

    def adc(self, pin: str, clock: int) -> int:
        """One conversion of the pin at world clock ``clock``; an unwired pin reads open (the chip's ADC_MAX)."""
        heater = self._by_sensor.get(pin)
        tick = max(round(clock / self.tick_clocks), self.tick)
        self.advance(tick)
        if pin == TEMPERATURE_PIN_NAME and (sensor := chip_sensor(self.chip.mcu_constant)) is not None:
            return sensor.adc(self.ambient_c + CHIP_ABOVE_AMBIENT_C, self.chip.adc_max)
        if heater is None:
            ambient = self._ambient_sensors.get(pin)
            if ambient is not None:
                return int(ambient.convert(np.array([self.ambient_c]), np.array([tick]))[0])
            return self.chip.adc_max
        sensor_c = heater.plant.temps_c()[SENSOR:SENSOR + 1]
        return int(heater.chain.convert(sensor_c, np.array([tick]))[0])

    def drive(self, pin: str, clock: int, on: int, period: int) -> None:
        """The MCU changes a pin at ``clock`` (see PinWave); clocks the plants passed are taken as now."""
        clock = max(clock, self.tick * self.tick_clocks)
        heater = self._by_pin.get(pin)
        if heater is not None:
            heater.pin.drive(clock, on, period)
        elif pin == self.fan_pin:
            self.fan.drive(clock, on, period)
            self._actions.push(round(clock / self.tick_clocks), self._apply_fan)
        elif self.probe is not None and pin == self.probe.pins.control_pin:
            self.probe.command(on / period)

    def reset_pins(self, clock: int) -> None:
        """A board reset: every output low from ``clock`` on."""
        for pin in (*self._by_pin, *([self.fan_pin] if self.fan_pin else [])):
            self.drive(pin, clock, 0, 1)

    def temps_c(self, heater: str) -> tuple[float, float]:
        """(sensor, block) of a heater's plant now (as far as it has run)."""
        sensor_c, block_c = self.heaters[heater].plant.temps_c()
        return float(sensor_c), float(block_c)

    # -- the world -----------------------------------------------------------------------------
    def advance(self, tick: int) -> None:
        """Run every plant to plant tick ``tick``, applying scenario events and fan changes on their ticks."""
        while True:
            due = self._actions.next_at()
            if due is None or due > tick:
                break
            self._run_to(due)
            for _, action, args in self._actions.pop_due(due):
                action(*args)
        self._run_to(tick)

    def _run_to(self, tick: int) -> None:
        """Every plant to ``tick``, in runs of at most RUN_TICKS (a run's maps grow with its length)."""
        while self.tick < tick:
            n = min(tick - self.tick, RUN_TICKS)
            for heater in self.heaters.values():
                heater.plant.relinearise()
                heater.plant.advance(heater.heater_input(self.tick, n))
                heater.pin.forget_before((self.tick + n) * self.tick_clocks)
            self.tick += n
        self.fan.forget_before(self.tick * self.tick_clocks)

    def _apply_fan(self) -> None:
        hotend = self.heaters.get("hotend")
        if hotend is not None:
            speed = 0.0 if self.fan_failed else self.fan.duty()
            plant = hotend.plant
            plant.set_inputs(speed, plant.flow_mm_s, plant.ambient_c)

    def _apply_event(self, event: Event) -> None:
        """A scenario event (faults, fan, flow, ambient); setpoints and gains are klippy's, not the board's."""
        heater = self.heaters.get(event.heater or "hotend")
        kind, value = event.kind, event.value
        if kind == "ambient":
            self.ambient_c = float(value)  # type: ignore[arg-type]  # parse_scenario: a number
            for each in self.heaters.values():
                each.plant.set_inputs(each.plant.fan, each.plant.flow_mm_s, self.ambient_c)
                each.chain.set_ambient(self.ambient_c, self.tick)
        elif kind == "fault" and value == "fan_failure":
            self.fan_failed = True
            self._apply_fan()
        elif heater is None:
            return
        elif kind == "flow":
            heater.plant.set_inputs(heater.plant.fan, float(value), heater.plant.ambient_c)  # type: ignore[arg-type]
        elif kind == "fan":
            heater.plant.set_inputs(0.0 if self.fan_failed else float(value),  # type: ignore[arg-type]
                                    heater.plant.flow_mm_s, heater.plant.ambient_c)
        elif value in (OPEN, SHORT, DETACHED):
            sensor_c = float(heater.plant.temps_c()[SENSOR])
            heater.chain.set_fault(str(value), self.tick, sensor_c, self.ambient_c)
        else:
            heater.mode = str(value)
