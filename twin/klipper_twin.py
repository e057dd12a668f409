"""The Klipper profile of the twin: Klipper's host heater control, the MCU's ADC and soft PWM, and
the plants on one clock, so a Klipper printer can be replayed and its klippy.log reproduced.

Time is Klipper's: host eventtime, print_time and estimated print_time are all the twin's time in
seconds. The plants step on their 1.024 ms tick; a time maps to the nearest tick. Per heater:

- the MCU sums SAMPLE_COUNT conversions SAMPLE_TIME apart every REPORT_TIME (src/adccmds.c) of
  the plant's sensor node through the thermistor divider, floor(2^bits R / (R + pullup)) each;
  the host gets the sum normalised by SAMPLE_COUNT * ADC_MAX at ``read_time = first sample +
  8 ms`` and converts it with Klipper's calc_temp (klippy/extras/thermistor.py);
- ``KlipperHeater.temperature_callback`` runs on that report; the PWM it sends takes effect on the
  pin at ``read_time + pwm_delay`` (0.3 s later): the actuation delay;
- the pin is the MCU's soft PWM (src/gpiocmds.c), exactly: each queued value restarts the cycle,
  pin on for ``int(value * cycle_ticks + 0.5)`` MCU clock ticks then off for the rest of
  ``cycle_ticks``, until the next value. The plant gets each tick's on-fraction (the energy is
  exact; edges are resolved to the tick's average);
- the MCU's ADC range check shuts everything down after RANGE_CHECK_COUNT summed readings in a row
  outside [min_temp, max_temp] ("ADC out of range");
- ``stats()`` every second (the Stats line and the main-thread watchdog) and ``VerifyHeater``
  every second; a runaway shuts the printer down: pins off from then on, no more reports.

The plant's heater input is only known 0.3 s ahead, which is all the plants need: each is
advanced in one run from one ADC window to the next (a LinearPlant run is one matrix product
however the pin switches), and reads its 8 samples from the same run's output map.

Kalico (the Klipper fork) is a flavour of the same loop, chosen by the config: a ``KalicoHeaterConfig``
(``kalico_extruder_setup``, ``kalico_bed_setup``) gives the heater Kalico's host code (firmware_port/kalico:
its PWM rules, pid_v, MPC), ``pid_calibrate`` runs Kalico's PID_CALIBRATE on it and ``mpc_calibrate`` its
MPC_CALIBRATE, waiting as Kalico's ``printer.wait_while`` does on the twin's clock. An MPC section naming its
part fan (``MpcConfig.cooling_fan``) reads the plant's fan; the twin has no toolhead, so MPC sees no extrusion.

Not modelled: the MCU's max_duration check on the heater pin (the host's resend rule keeps it
from firing while reports flow), MCU clock quantisation of event times (14 ns at 72 MHz), serial
latency, and the toolhead (``print_time`` in the Stats line is the twin's time).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from firmware_port.kalico import (
    CONTROLS_WITH_GAINS,
    ControlMPC,
    KalicoHeater,
    KalicoHeaterConfig,
    MpcCalibrate,
    MpcCalibration,
    PidCalibration,
)
from firmware_port.kalico import pid_calibrate as kalico_pid_calibrate
from firmware_port.kalico.pid_calibrate import TUNE_PID_TOL
from firmware_port.klipper import (
    CommandError,
    HeaterConfig,
    HeaterFault,
    KlipperHeater,
    PidCalibrate,
    VerifyHeater,
    invert_calibration,
)
from firmware_port.klipper.heater import CONTROL_PID, PID_PARAM_BASE, REPORT_TIME, SAMPLE_COUNT, SAMPLE_TIME
from firmware_port.controller import PidGains
from firmware_port.firmwares import STOCK_BED_GAINS, STOCK_HOTEND_GAINS
from firmware_port.thermistor import KLIPPER_SENSORS, SteinhartHart
from twin.clock import TICK_S, EventQueue, tick_near
from twin.engine import DISCONNECTED, NORMAL, STUCK_ON
from twin.engine_protocol import LaneHeater, Runs, Trip
from twin.limits import DURATION_MAX_S, NOISE_MAX_LSB, PHYSICAL_RANGE_C, check_trace_bytes, checked, checked_seed
from twin.linear import BLOCK, SENSOR
from twin.plants import DEFAULT_HOTEND, make_plant
from twin.result import KLIPPER_NAMES, RunResult

# klippy/extras/adc_temperature.py and klippy/mcu.py
RANGE_CHECK_COUNT = 4  # summed readings in a row outside the limits before "ADC out of range"
ADC_FIRST_SAMPLE_S = 1.0  # get_query_slot: int(estimated print_time + 1.5) at connect ...
QUERY_SLOT_S = 0.01  # ... + oid * 10 ms (here: the heater's index, real oids differ)
ADC_SUM_LIMIT = 1 << 16  # mcu.py: "ADC sample_count=%d too large for MCU" at sample_count*ADC_MAX >= this
# klippy/extras/thermistor.py
PULLUP_OHM = 4700.0
ADC_CLAMP = (0.00001, 0.99999)  # calc_temp clamps the normalised reading
DEFAULT_SENSOR = "EPCOS 100K B57560G104F"  # config/example-cartesian.cfg, extruder and bed
KLIPPER_HEATERS = {klipper: ours for ours, klipper in KLIPPER_NAMES.items()}  # Klipper's names -> the result's
# klippy/extras/heaters.py
PWM_CYCLE_TIME_S = 0.100  # pwm_cycle_time default; must be <= pwm_delay
# klippy/extras/statistics.py
STATS_INTERVAL_S = 1.0
# What a heater's records (reports, Stats lines, replies) hold per virtual second: about 1.5 kB
# (tracemalloc over 600 s of a heat-up); the bound that refuses a run whose records would not fit.
RECORD_BYTES_PER_S = 1600
# klippy/extras/heaters.py _wait_for_temperature: M109-style waits report once a second
WAIT_REPORT_S = 1.0
PID_CALIBRATE_TIMEOUT_S = 7200.0  # the twin's guard; Klipper waits until cancelled
WAIT_LIMIT_S = 7200.0  # the twin's guard on a Kalico command's waits; Kalico waits until cancelled
WAIT_INTERRUPTED = "Command interrupted"  # klippy/printer.py WaitInterruption: a wait ended by a shutdown

# klippy/extras/error_mcu.py: how klippy words an MCU shutdown (message, clarification, hint)
MCU_SHUTDOWN = "MCU shutdown"
MCU_NAME = "mcu"  # the main [mcu]
ADC_OUT_OF_RANGE = "ADC out of range"
ADC_RANGE_HINT = """
This generally occurs when a heater temperature exceeds
its configured min_temp or max_temp."""
SHUTDOWN_STATE = "Transition to shutdown state: "  # klippy.py invoke_shutdown's log line
NOT_HEATING = "Heater {} not heating at expected rate"  # verify_heater.py heater_fault's message, first line
PORT_LOGGERS = ("firmware_port.klipper", "firmware_port.kalico")  # their lines are klippy.log's

# Events due at the same time run in this order.
PRIO_USER, PRIO_ADC, PRIO_MCU_SHUTDOWN, PRIO_REPORT, PRIO_STATS, PRIO_VERIFY = range(6)


@dataclass(frozen=True)
class Mcu:
    """The board the heaters hang on: its clock (soft-PWM resolution) and ADC width."""

    name: str
    clock_hz: float
    adc_bits: int

    @property
    def adc_max(self) -> int:
        return (1 << self.adc_bits) - 1


STM32F103 = Mcu("stm32f103", 72e6, 12)  # 12-bit ADC: the default, as on most 32-bit boards
ATMEGA2560 = Mcu("atmega2560", 16e6, 10)  # AVR boards: 10-bit ADC


def calc_temp(part: SteinhartHart, pullup_ohm: float, adc: float) -> float:
    """Klipper's thermistor calc_temp: a normalised reading (0..1) to degC (no inline resistor)."""
    adc = max(ADC_CLAMP[0], min(ADC_CLAMP[1], adc))
    return part.temp_c(pullup_ohm * adc / (1.0 - adc))


def calc_adc(part: SteinhartHart, pullup_ohm: float, temp_c):
    """Klipper's thermistor calc_adc: the normalised reading R / (pullup + R) at temp_c (array ok)."""
    r = part.resistance_ohm(temp_c)
    return r / (pullup_ohm + r)


@dataclass(frozen=True)
class HeaterSetup:
    """One heater of the printer: Klipper's config section, the plant it heats, its thermistor."""

    config: HeaterConfig
    plant: Any  # the LinearPlant API: outputs(u, offsets), advance(u), temps_c()
    sensor: str | SteinhartHart = DEFAULT_SENSOR  # a KLIPPER_SENSORS name, or e.g. SteinhartHart.from_beta
    pullup_ohm: float = PULLUP_OHM
    pwm_cycle_time_s: float = PWM_CYCLE_TIME_S
    verify: dict | None = field(default_factory=dict)  # VerifyHeater options; None: no check
    noise_lsb: float = 0.0  # Gaussian noise of each ADC conversion, in LSB of the MCU's converter

    def __post_init__(self):
        for option in dataclasses.fields(self.config):  # Klipper's config reads floats as they come, NaN too
            if isinstance(value := getattr(self.config, option.name), (int, float)):
                checked(f"[{self.config.name}] {option.name}", value)
        if isinstance(self.sensor, str) and self.sensor not in KLIPPER_SENSORS:
            raise ValueError(f"unknown sensor_type {self.sensor!r}; valid: {', '.join(KLIPPER_SENSORS)}")
        if not 0.0 < self.pwm_cycle_time_s <= self.config.pwm_delay_s:
            raise ValueError(f"[{self.config.name}] pwm_cycle_time must be in (0, pwm_delay]")
        checked(f"[{self.config.name}] noise_lsb", self.noise_lsb, 0.0, NOISE_MAX_LSB, "LSB")

    @property
    def part(self) -> SteinhartHart:
        return KLIPPER_SENSORS[self.sensor] if isinstance(self.sensor, str) else self.sensor


def host_heater(config: HeaterConfig) -> KlipperHeater:
    """The host's heater for a section: Kalico's for a KalicoHeaterConfig, else Klipper's."""
    return KalicoHeater(config) if isinstance(config, KalicoHeaterConfig) else KlipperHeater(config)


EXAMPLE_EXTRUDER_GAINS = {"pid_kp": 22.2, "pid_ki": 1.08, "pid_kd": 114.0}  # config/example-cartesian.cfg
EXTRUDER_MAX_C, BED_MAX_C = 250.0, 130.0


def _setup(config_class: type[HeaterConfig], name: str, max_temp_c: float, plant, options: dict) -> HeaterSetup:
    limits = options.pop("min_temp_c", 0.0), options.pop("max_temp_c", max_temp_c)
    return HeaterSetup(config_class(name, *limits, **options), plant)


def extruder_setup(plant=None, **config) -> HeaterSetup:
    """[extruder] of Klipper's config/example-cartesian.cfg (pid_Kp 22.2, pid_Ki 1.08, pid_Kd 114,
    EPCOS 100K) with max_temp 250, on the default hotend plant; config overrides HeaterConfig fields."""
    return _setup(HeaterConfig, "extruder", EXTRUDER_MAX_C, make_plant("hotend") if plant is None else plant,
                  {**EXAMPLE_EXTRUDER_GAINS, **config})


def bed_setup(plant=None, **config) -> HeaterSetup:
    """[heater_bed] of config/example-cartesian.cfg (control: watermark, EPCOS 100K) with max_temp
    130, on the bed plant; config overrides HeaterConfig fields."""
    return _setup(HeaterConfig, "heater_bed", BED_MAX_C, make_plant("bed") if plant is None else plant,
                  {"control": "watermark", **config})


def kalico_extruder_setup(plant=None, **config) -> HeaterSetup:
    """``extruder_setup`` on Kalico, with Kalico's defaults: config overrides KalicoHeaterConfig fields
    (``control="mpc", mpc=MpcConfig(heater_power_w=40.0)``: MPC, which heats once it has its constants)."""
    gains = EXAMPLE_EXTRUDER_GAINS if config.get("control", "pid") in CONTROLS_WITH_GAINS else {}
    return _setup(KalicoHeaterConfig, "extruder", EXTRUDER_MAX_C, make_plant("hotend") if plant is None else plant,
                  {**gains, **config})


def kalico_bed_setup(plant=None, **config) -> HeaterSetup:
    """``bed_setup`` on Kalico (control: watermark unless config says otherwise)."""
    return _setup(KalicoHeaterConfig, "heater_bed", BED_MAX_C, make_plant("bed") if plant is None else plant,
                  {"control": "watermark", **config})


def _control(control: str, gains: PidGains) -> dict:
    """A section's ``control:`` and, for a control that takes them, its pid_Kp/Ki/Kd (M301's scale)."""
    if control not in CONTROLS_WITH_GAINS:
        return {"control": control}
    return {"control": control, "pid_kp": gains.kp, "pid_ki": gains.ki, "pid_kd": gains.kd}


class SoftPwm:
    """A heater pin driven by the MCU's soft PWM (src/gpiocmds.c digital_out with a cycle time).

    Each queued value restarts the cycle at its time: on for on_s, off for cycle_s - on_s, again
    and again until the next value. From time 0 the pin is off."""

    def __init__(self, cycle_time_s: float, clock_hz: float):
        self.cycle_ticks = int(cycle_time_s * clock_hz)  # mcu.py seconds_to_clock
        self.clock_hz = clock_hz
        self.cycle_s = self.cycle_ticks / clock_hz
        self.times_s = [0.0]  # event times, non-decreasing
        self.on_s = [0.0]  # on time per cycle of each event

    def __repr__(self) -> str:
        return f"SoftPwm(cycle {self.cycle_s:g} s, duty {self.on_s[-1] / self.cycle_s:.3f} from {self.times_s[-1]:g} s)"

    def queue(self, time_s: float, value: float) -> None:
        """A queue_digital_out: MCU_pwm.set_pwm quantises the duty to whole clock ticks."""
        on_ticks = int(max(0.0, min(1.0, value)) * self.cycle_ticks + 0.5)
        self.times_s.append(time_s)
        self.on_s.append(min(on_ticks, self.cycle_ticks) / self.clock_hz)

    def cut(self, time_s: float) -> None:
        """MCU shutdown: queued values are dropped and the pin is off from time_s."""
        keep = int(np.searchsorted(self.times_s, time_s, side="right"))
        del self.times_s[keep:], self.on_s[keep:]
        self.queue(time_s, 0.0)

    def prune(self, time_s: float) -> None:
        """Forget the values that ended before time_s."""
        first = int(np.searchsorted(self.times_s, time_s, side="right")) - 1
        if first > 0:
            del self.times_s[:first], self.on_s[:first]

    def duty_at(self, time_s: float) -> float:
        """The duty (on fraction of a cycle) in force at time_s."""
        return self.on_s[int(np.searchsorted(self.times_s, time_s, side="right")) - 1] / self.cycle_s

    def tick_duties(self, start_tick: int, n_ticks: int) -> np.ndarray:
        """The pin's on-fraction over each of n_ticks plant ticks from start_tick."""
        times, on = np.array(self.times_s), np.array(self.on_s)
        first, last = np.searchsorted(times, (start_tick * TICK_S, (start_tick + n_ticks) * TICK_S), side="right") - 1
        if first == last and on[first] in (0.0, self.cycle_s):  # one value, pin steady off or on
            return np.full(n_ticks, on[first] / self.cycle_s)
        edges = (start_tick + np.arange(n_ticks + 1)) * TICK_S
        # the on-time accumulated since times[0] at each tick edge, differenced
        base = np.concatenate(([0.0], np.cumsum(self._on_time(np.diff(times), on[:-1]))))
        seg = np.maximum(np.searchsorted(times, edges, side="right") - 1, 0)
        cumulative = base[seg] + self._on_time(np.maximum(edges - times[seg], 0.0), on[seg])
        return np.diff(cumulative) / TICK_S

    def _on_time(self, since_s: np.ndarray, on_s: np.ndarray) -> np.ndarray:
        """On-time within since_s of a value's start: whole cycles plus the part of the current one."""
        cycles = np.floor(since_s / self.cycle_s)
        # the remainder from the same quotient: np.mod can disagree with floor at a cycle's edge
        into_cycle_s = np.minimum(np.maximum(since_s - cycles * self.cycle_s, 0.0), self.cycle_s)
        return cycles * on_s + np.minimum(into_cycle_s, on_s)


class ReportRow(NamedTuple):
    """One sensor report of one heater, after the host handled it."""

    t_s: float  # read_time: first sample + 8 ms
    target_c: float
    temp_c: float  # last_temp: the raw report (what Stats prints)
    smoothed_c: float  # smoothed_temp: what M105, waits and verify_heater use
    pwm: float  # last_pwm_value: the last value sent (what Stats prints)
    duty: float  # the heater's duty in force at t_s (after the 0.3 s delay and any wiring fault)
    sensor_c: float  # true sensor node at t_s
    block_c: float  # true heater block at t_s


@dataclass(frozen=True)
class PidCalibrateResult:
    """What PID_CALIBRATE answered and what its relay test saw."""

    lines: list[str]  # the G-code reply, as pid_calibrate.py words it (a terminal shows "// ...")
    kp: float  # as saved by SAVE_CONFIG (3 decimals)
    ki: float
    kd: float
    peaks: list[tuple[float, float]]  # (temp_c, read_time_s); peaks[0] is Klipper's dummy (0, 0)
    tu_s: float  # 8 Kd / Kp: the period of the cycle Klipper picked
    ku: float  # Kp / (0.6 * 255), Klipper's (full-swing) relay Ku
    peak_to_peak_c: float
    started_s: float
    finished_s: float
    heattest: str  # what WRITE_FILE=1 writes to /tmp/heattest.txt


class _Channel:
    """A heater's runtime: host heater, verify check, plant, ADC and pin state."""

    def __init__(self, index: int, setup: HeaterSetup, mcu: Mcu, rng: np.random.Generator):
        self.heater = host_heater(setup.config)
        self.noise_lsb, self.rng = setup.noise_lsb, rng
        self.name = self.heater.short_name
        self.plant = setup.plant
        self.part = setup.part
        self.pullup_ohm = setup.pullup_ohm
        self.verify = None if setup.verify is None else VerifyHeater(self.heater, **setup.verify)
        self.pwm = SoftPwm(setup.pwm_cycle_time_s, mcu.clock_hz)
        mpc = getattr(setup.config, "mpc", None)
        if isinstance(self.heater.control, ControlMPC) and mpc is not None and mpc.cooling_fan:
            self.heater.control.fan_speed = lambda print_time: self.plant.fan
        self.mode = NORMAL
        self.plant_tick = 0  # the plant's state is at this tick
        self.first_sample_s = ADC_FIRST_SAMPLE_S + index * QUERY_SLOT_S
        self.adc_scale = float(1 << mcu.adc_bits)  # an ideal converter: floor(2^bits * ratio)
        self.adc_max = mcu.adc_max
        max_sum = SAMPLE_COUNT * mcu.adc_max
        self.inv_max_adc = 1.0 / max_sum
        # adc_temperature.setup_minmax -> MCU_adc._build_config: the range check limits of the sum
        limits = (calc_adc(self.part, self.pullup_ohm, t) for t in (self.heater.min_temp, self.heater.max_temp))
        low, high = sorted(limits)
        self.min_sum = max(0, min(0xFFFF, int(low * max_sum)))
        self.max_sum = max(0, min(0xFFFF, math.ceil(high * max_sum)))
        self.invalid_count = 0
        self.reports: list[ReportRow] = []
        self.sends: list[tuple[float, float, float]] = []  # (read_time, pwm_time, value) of each value sent

    def heater_input(self, start_tick: int, n_ticks: int) -> np.ndarray:
        """The plant's input over n ticks: the pin's on-fractions unless the wiring is faulty."""
        if self.mode == DISCONNECTED:
            return np.zeros(n_ticks)
        if self.mode == STUCK_ON:
            return np.ones(n_ticks)
        return self.pwm.tick_duties(start_tick, n_ticks)

    def advance_plant(self, tick: int, u: np.ndarray | None = None) -> None:
        """Run the plant up to ``tick`` in one run (u: its input, if already known)."""
        n = tick - self.plant_tick
        if n <= 0:
            return
        relinearise = getattr(self.plant, "relinearise", None)
        if relinearise is not None:
            relinearise()
        self.plant.advance(self.heater_input(self.plant_tick, n) if u is None else u)
        self.plant_tick = tick
        self.pwm.prune(tick * TICK_S)


class _LogList(logging.Handler):
    """Collects the Klipper port's log messages as klippy.log lines."""

    def __init__(self, twin: KlipperTwin):
        super().__init__(logging.INFO)
        self.twin = twin

    def emit(self, record: logging.LogRecord) -> None:
        self.twin.log.append((self.twin.time_s, record.getMessage()))


class KlipperHandle(LaneHeater):
    """A Klipper heater as a user sees it: the engine protocol's handle, and ``gains`` as on a ``Twin``'s."""

    def __init__(self, twin: KlipperTwin, name: str):
        heater = twin.heater(name)
        super().__init__(KLIPPER_HEATERS.get(name, name), lambda: heater.target_temp,
                         lambda value: twin.set_target(name, value), lambda: [heater.control])
        self._twin, self._heater = twin, heater

    @property
    def gains(self) -> PidGains:
        """PID gains on the 0..255 scale (pid_Kp/Ki/Kd, M301's); ValueError for a control without gains."""
        return self._twin.gains(self._heater.short_name)

    @gains.setter
    def gains(self, gains: PidGains) -> None:
        self._twin.set_gains(self._heater.short_name, gains)

    def __repr__(self) -> str:
        return f"KlipperHandle({self.name!r}, target_c={self.target_c:g}, control={self._heater.control!r})"


class KlipperTwin(Runs):
    """A Klipper printer's heaters on one clock: host control, MCU ADC and soft PWM, plants; one lane of the
    engine protocol (twin/engine_protocol.py), its heaters named as in the result ("hotend" for the extruder)."""

    n_lanes = 1

    def __init__(self, heaters: Sequence[HeaterSetup], mcu: Mcu = STM32F103, seed: int = 0):
        checked_seed("seed", seed)
        if SAMPLE_COUNT * mcu.adc_max >= ADC_SUM_LIMIT:
            raise ValueError(f"ADC sample_count={SAMPLE_COUNT} too large for MCU")
        self.mcu = mcu
        self.time_s = 0.0
        self.log: list[tuple[float, str]] = []  # (time, klippy.log line): Stats lines and the port's messages
        self.replies: list[tuple[float, str]] = []  # (time, G-code response) of the commands run here
        self.halted = False
        self.shutdown_message: str | None = None
        self._trip: Trip | None = None  # what shut the printer down, as a trip of the heater that caused it
        self.shutdown_time_s: float | None = None
        self._events = EventQueue()  # actions due at a time in seconds
        self._logging = False  # inside _klippy_logging
        with self._klippy_logging():
            self.channels: dict[str, _Channel] = {}
            streams = np.random.SeedSequence(seed).spawn(len(heaters))
            for index, setup in enumerate(heaters):
                channel = _Channel(index, setup, mcu, np.random.default_rng(streams[index]))
                if channel.name in self.channels:
                    raise ValueError(f"Heater {channel.name} already registered")
                self.channels[channel.name] = channel
        for channel in self.channels.values():
            self._push(channel.first_sample_s, PRIO_ADC, self._adc_sample, channel, 0)
            if channel.verify is not None:
                self._push(0.0, PRIO_VERIFY, self._verify, channel)
        self._push(0.0, PRIO_STATS, self._stats, 0)

    @classmethod
    def create(cls, firmware: str = CONTROL_PID, hotend: str | None = None, bed: str | None = None, *,
               ambient_c: float = 25.0, kalico: bool = False, **options) -> KlipperTwin:
        """A Klipper printer from ``Twin.create``'s arguments: the same plant presets (the hotend by default
        twin.plants.DEFAULT_HOTEND, no bed unless named) and, for a control with gains, the stock printer's
        (firmware_port/firmwares.py STOCK_*_GAINS, as pid_Kp/Ki/Kd). ``firmware`` is the heaters' ``control:``
        (pid or watermark; Kalico's also pid_v), ``kalico`` runs Kalico's host code, ``options`` go to
        ``KlipperTwin`` (mcu, seed)."""
        config = KalicoHeaterConfig if kalico else HeaterConfig
        heaters = [_setup(config, "extruder", EXTRUDER_MAX_C, make_plant(hotend or DEFAULT_HOTEND, ambient_c=ambient_c),
                          _control(firmware, STOCK_HOTEND_GAINS))]
        if bed is not None:
            heaters.append(_setup(config, "heater_bed", BED_MAX_C, make_plant(bed, ambient_c=ambient_c),
                                  _control(firmware, STOCK_BED_GAINS)))
        return cls(heaters, **options)

    # -- the outside world ----------------------------------------------------------------------
    def heater(self, name: str) -> KlipperHeater:
        """The host heater by its short name ("extruder", "heater_bed")."""
        return self._channel(name).heater

    def schedule(self, at_s: float, action: Callable[[KlipperTwin], None]) -> None:
        """Run ``action(twin)`` at time at_s (before the sensor reports due then)."""
        checked("at_s", at_s, 0.0, DURATION_MAX_S, "s")
        if at_s < self.time_s:
            raise ValueError(f"cannot schedule at {at_s} s: the twin is at {self.time_s} s")
        self._push(at_s, PRIO_USER, action, self)

    def set_target(self, name: str, temp_c: float, at_s: float | None = None) -> None:
        """SET_HEATER_TEMPERATURE HEATER=<name> TARGET=<temp_c>, now or at at_s."""
        checked("temp_c", temp_c)  # Klipper's range check lets NaN through: full power
        heater = self.heater(name)
        if at_s is None:
            heater.set_target(temp_c)
            return
        if temp_c and not heater.min_temp <= temp_c <= heater.max_temp:
            heater.set_target(temp_c)  # raises Klipper's "Requested temperature ... out of range"
        self.schedule(at_s, lambda twin: heater.set_target(temp_c))

    def schedule_targets(self, name: str, times_s: Sequence[float], targets_c: Sequence[float]) -> None:
        """Replay a logged target sequence: set_target at the first sample and at every change."""
        last = None
        for t_s, target_c in zip(times_s, targets_c):
            if target_c != last:
                self.set_target(name, float(target_c), at_s=float(t_s))
                last = target_c

    def set_heater_mode(self, name: str, mode: str, at_s: float | None = None) -> None:
        """Wiring faults: normal, heater_disconnected (no power) or heater_stuck_on (MOSFET shorted)."""
        if mode not in (NORMAL, DISCONNECTED, STUCK_ON):
            raise ValueError(f"not a heater mode: {mode!r}")
        channel = self._channel(name)

        def apply(twin):
            channel.advance_plant(tick_near(twin.time_s))
            channel.mode = mode

        if at_s is None:
            apply(self)
        else:
            self.schedule(at_s, apply)

    @property
    def handles(self) -> dict[str, KlipperHandle]:
        """Every heater's handle by its name in the result: its target (SET_HEATER_TEMPERATURE), its control,
        its gains."""
        handles = (KlipperHandle(self, name) for name in self.channels)
        return {handle.name: handle for handle in handles}

    def gains(self, name: str) -> PidGains:
        """A heater's PID gains on the 0..255 scale (pid_Kp/Ki/Kd); ValueError for a control without gains."""
        control = self.heater(name).control
        if not all(hasattr(control, gain) for gain in ("kp", "ki", "kd")):
            raise ValueError(f"heater {name}: {type(control).__name__} has no PID gains")
        return PidGains(*(getattr(control, gain) * PID_PARAM_BASE for gain in ("kp", "ki", "kd")))

    def set_gains(self, name: str, gains: PidGains) -> None:
        """New PID gains for a heater whose ``control:`` takes them: a fresh control from its section with these
        as pid_Kp/Ki/Kd, the target kept (as M301 changes a Marlin PID's gains while it heats)."""
        heater = self.heater(name)
        if heater.config.control not in CONTROLS_WITH_GAINS:
            raise ValueError(f"heater {name}: control {heater.config.control} has no PID gains")
        heater.control = heater.new_control(dataclasses.replace(heater.config, **_control(heater.config.control,
                                                                                          gains)))

    def trips(self) -> list[Trip]:
        """What shut the printer down, if anything did: the heater and the shutdown's reason."""
        return [] if self._trip is None else [self._trip]

    def schedule_plants(self, at_s: float, action: Callable[[Any], None]) -> None:
        """Run ``action(plant)`` on every heater's plant at ``at_s``, each first run to that time."""
        def apply(twin: KlipperTwin) -> None:
            for channel in twin.channels.values():
                channel.advance_plant(tick_near(twin.time_s))
                action(channel.plant)

        self.schedule(at_s, apply)

    def __repr__(self) -> str:
        heaters = ", ".join(f"{name} ({type(c.heater).__name__}, {c.heater.config.control}, "
                            f"{getattr(c.plant, 'preset', type(c.plant).__name__)})"
                            for name, c in self.channels.items())
        return f"KlipperTwin({heaters}; mcu {self.mcu.name}, t={self.time_s:g} s{', halted' if self.halted else ''})"

    def set_plant_inputs(self, name: str, fan: float, flow_mm_s: float, ambient_c: float,
                         at_s: float | None = None) -> None:
        """The plant's part fan (0..1), filament flow (mm/s) and ambient (degC), now or at at_s."""
        checked("fan", fan, 0.0, 1.0)
        checked("flow_mm_s", flow_mm_s)
        checked("ambient_c", ambient_c, *PHYSICAL_RANGE_C, "C", above=True)
        channel = self._channel(name)

        def apply(twin):
            channel.advance_plant(tick_near(twin.time_s))
            channel.plant.set_inputs(fan, flow_mm_s, ambient_c)

        if at_s is None:
            apply(self)
        else:
            self.schedule(at_s, apply)

    def run_until(self, t_s: float) -> None:
        """Advance the clock to t_s seconds, running every event due up to and including it (at most
        DURATION_MAX_S; ValueError if the records would outgrow memory)."""
        checked("t_s", t_s, 0.0, DURATION_MAX_S, "s")
        check_trace_bytes(t_s, t_s * RECORD_BYTES_PER_S * len(self.channels), "the Klipper twin keeps every report: run shorter")
        if t_s < self.time_s:
            raise ValueError(f"cannot run back to {t_s} s from {self.time_s} s")
        with self._klippy_logging():
            for time_s, action, args in self._events.pop_due(t_s):
                self.time_s = time_s
                action(*args)
        self.time_s = t_s

    def pid_calibrate(self, name: str, target_c: float,
                      timeout_s: float = PID_CALIBRATE_TIMEOUT_S) -> PidCalibrateResult:
        """PID_CALIBRATE HEATER=<name> TARGET=<target_c>: run the relay test until it finishes.

        Waits as Klipper does (a check and an M105-style reply every second). Raises CommandError
        ("pid_calibrate interrupted") on a shutdown or after timeout_s. A Kalico heater: kalico_pid_calibrate."""
        checked("target_c", target_c)
        checked("timeout_s", timeout_s, 0.0, DURATION_MAX_S, "s")
        heater = self.heater(name)
        if isinstance(heater, KalicoHeater):
            raise ValueError(f"heater {name} runs Kalico: use kalico_pid_calibrate")
        started_s = self.time_s
        with self._klippy_logging():
            calibrate = PidCalibrate(heater, target_c)
        eventtime = self.time_s
        while not self.halted and calibrate.check_busy(eventtime) and eventtime - started_s < timeout_s:
            self.replies.append((eventtime, self.m105(eventtime)))
            eventtime += WAIT_REPORT_S
            self.run_until(eventtime)
        with self._klippy_logging():
            try:
                lines = calibrate.finish()
            except CommandError as error:
                self.replies.append((self.time_s, f"!! {error}"))
                raise
        self.replies.append((self.time_s, "// " + "\n// ".join(lines)))
        options = calibrate.saved_options
        kp, ki, kd = (float(options[key]) for key in ("pid_Kp", "pid_Ki", "pid_Kd"))
        # 8 Kd / Kp: Kd's 3 saved decimals keep Tu far closer than Ki's do in 2 Kp / Ki
        _, tu_s, ku, peak_to_peak_c = invert_calibration(kp, ki, kd, heater.max_power)
        return PidCalibrateResult(lines, kp, ki, kd, list(calibrate.tune.peaks), tu_s, ku, peak_to_peak_c,
                                  started_s, self.time_s, calibrate.tune.heattest_text())

    def kalico_pid_calibrate(self, name: str, target_c: float, tolerance: float = TUNE_PID_TOL) -> PidCalibration:
        """Kalico's PID_CALIBRATE HEATER=<name> TARGET=<target_c> [TOLERANCE=] on a Kalico heater, to the end.
        Raises CommandError ("pid_calibrate interrupted", "Command interrupted" on a shutdown)."""
        heater = self._kalico_heater(name)
        with self._klippy_logging(), self._command_errors():
            return kalico_pid_calibrate(self, heater, target_c, tolerance, heater_name=name)

    def mpc_calibrate(self, name: str, **options) -> MpcCalibration:
        """Kalico's MPC_CALIBRATE HEATER=<name> on a heater with control: mpc, to the end; options are
        MpcCalibrate's (target_c, threshold_c, use_delta, ...). Raises CommandError ("MPC_CALIBRATE failed:
        ...") if it fails. ``MpcCalibration.config(mpc)`` is the section after SAVE_CONFIG."""
        heater = self._kalico_heater(name)
        with self._klippy_logging(), self._command_errors():
            return MpcCalibrate(self, heater, **options).run()

    # -- what Kalico's commands ask of the printer (firmware_port.kalico.Printer) --------------------
    def monotonic(self) -> float:
        return self.time_s

    def wait_while(self, condition: Callable[[float], bool], interval_s: float = 1.0) -> None:
        """klippy's printer.wait_while on the twin's clock: condition(eventtime) now and every interval_s
        after until False; CommandError("Command interrupted") once the printer has shut down, or after
        WAIT_LIMIT_S (the twin's guard)."""
        started_s = eventtime = self.time_s
        while condition(eventtime):
            if self.halted:
                raise CommandError(WAIT_INTERRUPTED)
            if eventtime - started_s > WAIT_LIMIT_S:
                raise CommandError(f"{WAIT_INTERRUPTED}: the twin's wait limit of {WAIT_LIMIT_S:.0f} s passed")
            eventtime += interval_s
            self.run_until(eventtime)

    def respond_info(self, text: str) -> None:
        """gcode.respond_info: the message's lines, stripped, each as "// <line>"."""
        self.respond_raw("// " + "\n// ".join(line.strip() for line in text.strip().split("\n")))

    def respond_raw(self, text: str) -> None:
        self.replies.append((self.time_s, text))

    def set_part_fan(self, heater_name: str, speed: float) -> None:
        """The part fan blowing on the heater's plant at speed 0..1 from now (flow and ambient kept)."""
        plant = self._channel(heater_name).plant
        self.set_plant_inputs(heater_name, speed, plant.flow_mm_s, plant.ambient_c)

    def m105(self, eventtime: float) -> str:
        """Klipper's M105 reply: "T0:<smoothed> /<target> B:..." for the heaters with a G-code id."""
        out = []
        for gcode_id, name in sorted((_gcode_id(name), name) for name in self.channels if _gcode_id(name)):
            cur, target = self.channels[name].heater.get_temp(eventtime)
            out.append(f"{gcode_id}:{cur:.1f} /{target:.1f}")
        return " ".join(out) if out else "T:0"

    # -- what it recorded ---------------------------------------------------------------------
    @property
    def stats_lines(self) -> list[str]:
        return [text for _, text in self.log if text.startswith("Stats ")]

    def klippy_log(self) -> str:
        """The log as klippy.log would have it (tools.logs.parse_klippy_log reads it)."""
        return "".join(text + "\n" for _, text in self.log)

    def reports(self, name: str) -> list[ReportRow]:
        return self._channel(name).reports

    def column(self, name: str, field_name: str) -> np.ndarray:
        """One ReportRow field of a heater's reports as an array."""
        index = ReportRow._fields.index(field_name)
        return np.array([row[index] for row in self._channel(name).reports], dtype=float)

    def result(self) -> RunResult:
        """Every heater's reports as one RunResult on the first heater's report times (the others
        held from their last report): target, the raw reading (what Stats prints) as measured_c,
        the true sensor and block temperatures and the duty in force."""
        names = list(self.channels)
        t_s = self.column(names[0], "t_s")
        columns = {}
        for name in names:
            own_t = self.column(name, "t_s")
            at = np.clip(np.searchsorted(own_t, t_s, side="right") - 1, 0, max(len(own_t) - 1, 0))
            fields = {"target_c": "target_c", "measured_c": "temp_c", "block_c": "block_c",
                      "sensor_c": "sensor_c", "duty": "duty"}
            columns[KLIPPER_HEATERS.get(name, name)] = {f: self.column(name, src)[at] if len(own_t) else
                                                        np.full(len(t_s), np.nan) for f, src in fields.items()}
        return RunResult.from_columns(t_s, columns, events=list(self.log), label="klipper")

    def sends(self, name: str) -> list[tuple[float, float, float]]:
        """(read_time, pwm_time, value) of every PWM value the host sent to the MCU."""
        return self._channel(name).sends

    # -- events ---------------------------------------------------------------------------------
    def _kalico_heater(self, name: str) -> KalicoHeater:
        heater = self.heater(name)
        if not isinstance(heater, KalicoHeater):
            raise ValueError(f"heater {name} runs Klipper: give it a KalicoHeaterConfig (kalico_extruder_setup)")
        return heater

    @contextmanager
    def _command_errors(self):
        """A command's error also goes to the console as "!! <message>", as klippy reports it."""
        try:
            yield
        except CommandError as error:
            self.replies.append((self.time_s, f"!! {error}"))
            raise

    def _channel(self, name: str) -> _Channel:
        try:
            return self.channels[name]
        except KeyError:
            raise ValueError(f"unknown heater {name!r}; valid: {', '.join(self.channels)}") from None

    def _push(self, time_s: float, prio: int, action: Callable, *args) -> None:
        self._events.push(time_s, action, *args, priority=prio)

    def _adc_sample(self, channel: _Channel, k: int) -> None:
        """The MCU's k-th summed reading: 8 conversions from the first sample time on."""
        if self.halted:
            return
        first_s = channel.first_sample_s + k * REPORT_TIME
        read_time = first_s + SAMPLE_COUNT * SAMPLE_TIME
        start = tick_near(first_s)
        offsets = tuple(tick_near(first_s + i * SAMPLE_TIME) - start for i in range(SAMPLE_COUNT))
        offsets += (tick_near(read_time) - start,)
        # one input array: the run up to the first sample, then the window the samples see
        run = start - channel.plant_tick
        u = channel.heater_input(channel.plant_tick, run + offsets[-1])
        channel.advance_plant(start, u[:run])
        temps = channel.plant.outputs(u[run:], offsets)
        analog = calc_adc(channel.part, channel.pullup_ohm, temps[:-1, SENSOR]) * channel.adc_scale
        if channel.noise_lsb:
            analog = analog + channel.noise_lsb * channel.rng.standard_normal(SAMPLE_COUNT)
        value = int(np.clip(np.floor(analog), 0, channel.adc_max).sum())
        self._push(channel.first_sample_s + (k + 1) * REPORT_TIME, PRIO_ADC, self._adc_sample, channel, k + 1)
        if channel.min_sum <= value <= channel.max_sum:
            channel.invalid_count = 0
        else:
            channel.invalid_count += 1
            if channel.invalid_count >= RANGE_CHECK_COUNT:
                last_s = first_s + (SAMPLE_COUNT - 1) * SAMPLE_TIME
                self._push(last_s, PRIO_MCU_SHUTDOWN, self._adc_out_of_range, channel)
        self._push(read_time, PRIO_REPORT, self._report, channel, value, temps[-1])

    def _report(self, channel: _Channel, value: int, true_c: np.ndarray) -> None:
        """analog_in_state reaches the host: calc_temp, then the heater's control."""
        if self.halted:
            return
        read_time = self.time_s
        heater = channel.heater
        event = heater.temperature_callback(read_time, calc_temp(channel.part, channel.pullup_ohm,
                                                                 value * channel.inv_max_adc))
        if event is not None:
            channel.pwm.queue(event.time_s, event.value)
            channel.sends.append((read_time, event.time_s, event.value))
        duty = {DISCONNECTED: 0.0, STUCK_ON: 1.0}.get(channel.mode, channel.pwm.duty_at(read_time))
        channel.reports.append(ReportRow(read_time, heater.target_temp, heater.last_temp, heater.smoothed_temp,
                                         heater.last_pwm_value, duty, float(true_c[SENSOR]), float(true_c[BLOCK])))

    def _adc_out_of_range(self, channel: _Channel) -> None:
        heater = channel.heater
        clarify = (f"Sensor '{heater.name}' temperature {heater.last_temp:.3f} not in range "
                   f"{heater.min_temp:.3f}:{heater.max_temp:.3f}")
        message = f"MCU '{MCU_NAME}' shutdown: {ADC_OUT_OF_RANGE}\n\n{clarify}\n{ADC_RANGE_HINT}"
        self._shutdown(MCU_SHUTDOWN, message, Trip(0, KLIPPER_HEATERS.get(channel.name, channel.name),
                                                   ADC_OUT_OF_RANGE))

    def _verify(self, channel: _Channel) -> None:
        if self.halted:
            return
        try:
            next_s = channel.verify.check_event(self.time_s)  # type: ignore[union-attr]  # pushed only with a verify
        except HeaterFault as fault:
            self._shutdown(str(fault), str(fault), Trip(0, KLIPPER_HEATERS.get(channel.name, channel.name),
                                                        str(fault).split("\n")[0]))
            return
        self._push(next_s, PRIO_VERIFY, self._verify, channel)

    def _stats(self, k: int) -> None:
        """statistics.py: every heater's stats() (it feeds the watchdog); a line if one is active."""
        eventtime = k * STATS_INTERVAL_S
        stats = [channel.heater.stats(eventtime) for channel in self.channels.values()]
        if any(active for active, _ in stats):
            fragments = " ".join(fragment for _, fragment in stats)
            toolhead = f"print_time={eventtime:.3f} buffer_time=0.000 print_stall=0"
            self.log.append((eventtime, f"Stats {eventtime:.1f}: {fragments} {toolhead}"))
        self._push((k + 1) * STATS_INTERVAL_S, PRIO_STATS, self._stats, k + 1)

    def _shutdown(self, log_message: str, message: str, trip: Trip) -> None:
        """klippy's invoke_shutdown: every heater off from now on; no more reports or checks."""
        if self.halted:
            return
        self.halted = True
        self._trip = trip
        self.shutdown_time_s = self.time_s
        self.shutdown_message = message
        self.log.append((self.time_s, SHUTDOWN_STATE + log_message))
        for channel in self.channels.values():
            channel.heater.handle_shutdown()
            channel.pwm.cut(self.time_s)

    @contextmanager
    def _klippy_logging(self):
        """Collect the Klipper and Kalico ports' log lines into self.log; if INFO was off for them, turn it
        on for the twin only (no propagation), so a caller's log is not flooded. Re-entrant: a command's
        waits run the clock inside it."""
        if self._logging:
            yield
            return
        handler = _LogList(self)
        loggers = [logging.getLogger(name) for name in PORT_LOGGERS]
        saved = [(logger.level, logger.propagate) for logger in loggers]
        for logger in loggers:
            if not logger.isEnabledFor(logging.INFO):
                logger.setLevel(logging.INFO)
                logger.propagate = False
            logger.addHandler(handler)
        self._logging = True
        try:
            yield
        finally:
            self._logging = False
            for logger, (level, propagate) in zip(loggers, saved):
                logger.removeHandler(handler)
                logger.setLevel(level)
                logger.propagate = propagate


def _gcode_id(short_name: str) -> str | None:
    """heaters.py: extruder -> T0, extruderN -> TN, heater_bed -> B; others have none by default."""
    if short_name == "heater_bed":
        return "B"
    if short_name.startswith("extruder"):
        return f"T{short_name[len('extruder'):] or 0}"
    return None
