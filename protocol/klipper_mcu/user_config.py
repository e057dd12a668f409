"""A user's printer.cfg, read for what the twin MCU must serve: the chip its [mcu] is, the heaters
and thermistors on their pins, the part fan, and the steppers' axes with their endstops.

Klipper's own reading rules, as far as the twin needs them (klippy/configfile.py): ``key: value``
or ``key = value``, ``#`` and ``;`` comments, indented continuation lines, ``[include glob]``
relative to the including file, and the SAVE_CONFIG block (``#*# `` lines after its marker)
over the rest. Pins lose their ``^ ~ !`` modifiers (the MCU sees the bare pin; ``!`` is kept as
``inverted``). The chip: ``--mcu``, else the config's "compiled for ..." comment (Klipper's
example configs say it), else the smallest AVR whose ports hold every pin, else the first STM32 of
dictionary.CHIPS (the stm32f103 of most 32-bit printers' boards) that has them all; among those, one
whose ADC reads every thermistor's pin, where one does (PF3 and PF4: an stm32f407).
"""

from __future__ import annotations

import configparser
import glob
import re
from dataclasses import dataclass, field
from pathlib import Path

from protocol.klipper_mcu.dictionary import CHIPS, DEFAULT_SENSOR, Chip

PULLUP_OHM = 4700.0  # klippy/extras/thermistor.py's default pullup_resistor
AUTOSAVE_MARKER = "#*# <---------------------- SAVE_CONFIG ---------------------->"
COMPILED_FOR = re.compile(r"compiled for (?:an |a |the )?(?:AVR |STM32 |Atmel |SAM )?(\w+)", re.IGNORECASE)
HEATER_SECTIONS = {"extruder": "hotend", "heater_bed": "bed"}  # the twin's plants by Klipper section
FULL_STEPS = 200  # klippy/stepper.py full_steps_per_rotation default


class ConfigError(ValueError):
    """A printer.cfg the twin cannot serve; the message names the file, section and option."""


@dataclass(frozen=True)
class Pin:
    name: str  # the bare pin, e.g. "PC2"
    inverted: bool = False
    mcu: str = "mcu"  # the [mcu ...] it belongs to


@dataclass(frozen=True)
class HeaterPins:
    section: str
    heater: str  # "hotend" or "bed": which plant
    heater_pin: str
    sensor_pin: str
    sensor_type: str
    pullup_ohm: float
    max_temp_c: float


@dataclass(frozen=True)
class SensorPin:
    """A thermistor no simulated heater warms (a [temperature_sensor], a second extruder): at ambient."""

    section: str
    pin: str
    sensor_type: str
    pullup_ohm: float


@dataclass(frozen=True)
class StepperPins:
    """A stepper on the main MCU: klippy's millimetres per MCU step, and its dir_pin's ``!``."""

    section: str
    step_pin: str
    dir_inverted: bool
    step_mm: float


@dataclass(frozen=True)
class RailPins:
    """A coordinate of the printer: the middle of [min, max] where it starts, plus each stepper's millimetres
    times its weight (klippy's kinematics: corexy x = (a + b) / 2)."""

    position_min_mm: float
    position_max_mm: float
    terms: tuple[tuple[StepperPins, float], ...]


@dataclass(frozen=True)
class AxisPins:
    """A stepper with an endstop, as klippy's PrinterRail sees it: millimetres per MCU step, the
    direction in which it homes, and the steppers whose travel moves its switch (``terms``)."""

    section: str
    step_pin: str
    dir_inverted: bool
    endstop: Pin
    step_mm: float
    position_endstop_mm: float
    position_min_mm: float
    position_max_mm: float
    homes_positive: bool
    terms: tuple[tuple[StepperPins, float], ...] = ()

    @property
    def rail(self) -> RailPins:
        return RailPins(self.position_min_mm, self.position_max_mm, self.terms)


@dataclass(frozen=True)
class ProbePins:
    """A [bltouch] or [probe] on the main MCU: its sensor pin, a BLTouch's servo control pin (None: a probe
    that is always deployed), and the nozzle's height at which it triggers (z_offset)."""

    section: str
    sensor: Pin
    control_pin: str | None
    z_offset_mm: float
    z: RailPins | None  # the nozzle's height (None: not a linear sum of steppers, as on a delta)


@dataclass(frozen=True)
class ThermistorSpec:
    """A config's [thermistor NAME]: (temperature C, resistance ohm) points, three, or one with ``beta``."""

    section: str
    points: tuple[tuple[float, float], ...]
    beta: float | None = None


@dataclass(frozen=True)
class UserConfig:
    path: Path
    chip: Chip
    heaters: tuple[HeaterPins, ...]
    sensors: tuple[SensorPin, ...]
    fan_pin: str | None
    axes: tuple[AxisPins, ...]
    serial: str
    probe: ProbePins | None = None
    thermistors: dict[str, ThermistorSpec] = field(default_factory=dict)  # the config's own [thermistor NAME]s


def parse_pin(text: str) -> Pin:
    """``^!PC2`` -> Pin("PC2", inverted=True); ``probe:z_virtual_endstop`` -> Pin on mcu "probe"."""
    text = text.strip()
    inverted = False
    while text[:1] in "^~!":
        inverted ^= text[0] == "!"
        text = text[1:].strip()
    mcu, _, name = text.rpartition(":")
    return Pin(name.strip(), inverted, mcu.strip() or "mcu")


def read_sections(path: Path) -> configparser.RawConfigParser:
    """The config with its includes and SAVE_CONFIG block, as klippy reads it."""
    parser = configparser.RawConfigParser(delimiters=(":", "="), comment_prefixes=("#", ";"),
                                          inline_comment_prefixes=("#", ";"), strict=False, interpolation=None)
    _read_file(parser, path, set())
    return parser


def _read_file(parser: configparser.RawConfigParser, path: Path, seen: set[Path]) -> None:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read it: {exc}") from None
    seen.add(path.resolve())
    main, _, autosave = text.partition(AUTOSAVE_MARKER)
    body: list[str] = []
    for line in main.splitlines():
        include = re.match(r"\s*\[include\s+(.+?)\s*\]\s*$", line)
        if include is None:
            body.append(line)
            continue
        _flush(parser, body, path)
        body = []
        matches = sorted(glob.glob(str(path.parent / include.group(1))))
        if not matches and not glob.has_magic(include.group(1)):
            raise ConfigError(f"{path}: [include {include.group(1)}]: no such file")
        for match in matches:
            if Path(match).resolve() not in seen:
                _read_file(parser, Path(match), seen)
    _flush(parser, body, path)
    saved = [line[4:] if line.startswith("#*# ") else line.lstrip("#*") for line in autosave.splitlines()]
    _flush(parser, saved, path)


def _flush(parser: configparser.RawConfigParser, lines: list[str], path: Path) -> None:
    try:
        parser.read_string("\n".join(lines), source=str(path))
    except configparser.Error as exc:
        raise ConfigError(f"{path}: {' '.join(str(exc).split())}") from None


def read_user_config(path: Path, chip_name: str | None = None) -> UserConfig:
    """What the twin serves for ``path``'s [mcu] (ConfigError: a one-line reason)."""
    parser = read_sections(path)
    if not parser.has_section("mcu"):
        raise ConfigError(f"{path}: no [mcu] section: the twin serves the printer's main MCU")
    pins = _main_mcu_pins(parser)
    analog = [parse_pin(parser.get(section, "sensor_pin")).name for section in parser.sections()
              if parser.has_option(section, "sensor_pin") and parse_pin(parser.get(section, "sensor_pin")).mcu == "mcu"]
    chip = _chip(path, chip_name, pins, analog)
    get = _Getter(parser, path)
    heaters, sensors = [], []
    for section in parser.sections():
        if not parser.has_option(section, "sensor_pin"):
            continue
        sensor_pin = parse_pin(parser.get(section, "sensor_pin"))
        if sensor_pin.mcu != "mcu":
            continue
        sensor_type = parser.get(section, "sensor_type", fallback=DEFAULT_SENSOR).strip()
        pullup = get.number(section, "pullup_resistor", PULLUP_OHM)
        if section in HEATER_SECTIONS and parser.has_option(section, "heater_pin"):
            heaters.append(HeaterPins(section, HEATER_SECTIONS[section], parse_pin(parser.get(section, "heater_pin")).name,
                                      sensor_pin.name, sensor_type, pullup, get.number(section, "max_temp", 300.0)))
        else:
            sensors.append(SensorPin(section, sensor_pin.name, sensor_type, pullup))
    fan = parse_pin(parser.get("fan", "pin")) if parser.has_option("fan", "pin") else None
    return UserConfig(path, chip, tuple(heaters), tuple(sensors), fan.name if fan and fan.mcu == "mcu" else None,
                      tuple(_axes(parser, get)), parser.get("mcu", "serial", fallback="").strip(), _probe(parser, get),
                      _thermistors(parser, get))


def _thermistors(parser: configparser.RawConfigParser, get: _Getter) -> dict[str, ThermistorSpec]:
    """[thermistor NAME] sections as klippy/extras/thermistor.py reads them: three (temperature, resistance)
    points, or one and a beta."""
    specs = {}
    for section in parser.sections():
        if section.startswith("thermistor "):
            points = [(get.number(section, "temperature1"), get.number(section, "resistance1"))]
            beta = get.number(section, "beta") if parser.has_option(section, "beta") else None
            if beta is None:
                points += [(get.number(section, f"temperature{k}"), get.number(section, f"resistance{k}")) for k in (2, 3)]
            specs[section.split(None, 1)[1]] = ThermistorSpec(section, tuple(points), beta)
    return specs


def _main_mcu_pins(parser: configparser.RawConfigParser) -> list[str]:
    names = []
    for section in parser.sections():
        for option, value in parser.items(section):
            if option.endswith("_pin") or option == "pin":
                pin = parse_pin(value.split(",")[0])
                if pin.mcu == "mcu" and re.fullmatch(r"P[A-Z]\d+", pin.name):
                    names.append(pin.name)
    return names


def _chip(path: Path, chip_name: str | None, pins: list[str], analog: list[str]) -> Chip:
    """The chip ``chip_name`` or the config's comment names, else one with every pin (its thermistors' on its
    ADC where one has them all)."""
    if chip_name is None:
        said = COMPILED_FOR.search(" ".join(path.read_text(errors="replace").replace("#", " ").split()))
        chip_name = said.group(1).lower() if said is not None else None
    if chip_name is None:
        fitting = [c for c in CHIPS.values() if all(_has(c, p) for p in pins)]
        if not fitting:
            raise ConfigError(f"{path}: no chip the twin knows has every pin of [mcu] ({', '.join(sorted(set(pins)))}); "
                              f"the twin serves {', '.join(CHIPS)}")
        fitting = [c for c in fitting if set(analog) <= set(c.adc_pins)] or fitting
        avrs = [c for c in fitting if c.port_pins == 8]
        return min(avrs, key=lambda c: len(c.ports)) if avrs else fitting[0]
    if chip_name not in CHIPS:
        raise ConfigError(f"{path}: the twin cannot serve an MCU compiled for {chip_name}; it serves {', '.join(CHIPS)}")
    chip = CHIPS[chip_name]
    missing = sorted({p for p in pins if not _has(chip, p)})
    if missing:
        raise ConfigError(f"{path}: pins the {chip.name} does not have: {', '.join(missing)}")
    return chip


def _has(chip: Chip, pin: str) -> bool:
    try:
        chip.pin_number(pin)
    except ValueError:
        return False
    return True


class _Getter:
    def __init__(self, parser: configparser.RawConfigParser, path: Path):
        self.parser, self.path = parser, path

    def number(self, section: str, option: str, default: float | None = None) -> float:
        if not self.parser.has_option(section, option):
            if default is None:
                raise ConfigError(f"{self.path}: [{section}] needs {option}")
            return default
        text = self.parser.get(section, option)
        try:
            return float(text)
        except ValueError:
            raise ConfigError(f"{self.path}: [{section}] {option}: {text!r} is not a number") from None


def _axes(parser: configparser.RawConfigParser, get: _Getter) -> list[AxisPins]:
    """Each stepper_* section with an endstop on the main MCU (stepper_z1 & co. take stepper_z's
    positions, as klippy's rail does), with the steppers that move its switch."""
    steppers = _steppers(parser, get)
    kinematics = _kinematics(parser)
    axes = []
    for section, stepper in steppers.items():
        if not parser.has_option(section, "endstop_pin"):
            continue
        endstop = _endstop_pin(parser, parser.get(section, "endstop_pin"))
        if endstop.mcu != "mcu":
            continue
        rail = _rail(parser, section)
        low, high, at = _travel(parser, get, rail)
        homes_positive = _homes_up(parser, rail) or at >= high - (high - low) / 4
        axes.append(AxisPins(section, stepper.step_pin, stepper.dir_inverted, endstop, stepper.step_mm, at, low, high,
                             homes_positive, _terms(kinematics, section, steppers)))
    return axes


def _endstop_pin(parser: configparser.RawConfigParser, text: str) -> Pin:
    """An endstop_pin's pin; a TMC driver's virtual_endstop (sensorless homing) is its driver's diag_pin, which
    the driver raises where the carriage stalls at the end of its travel (klippy/extras/tmc.py)."""
    pin = parse_pin(text)
    driver = pin.mcu.replace("_", " ", 1)  # "tmc2209_stepper_x" -> the section [tmc2209 stepper_x]
    if pin.name == "virtual_endstop" and driver.startswith("tmc") and parser.has_option(driver, "diag_pin"):
        return parse_pin(parser.get(driver, "diag_pin"))
    return pin


def _steppers(parser: configparser.RawConfigParser, get: _Getter) -> dict[str, StepperPins]:
    """Each stepper_* section whose steps the main MCU makes, by section."""
    steppers = {}
    for section in parser.sections():
        if not section.startswith("stepper_") or not parser.has_option(section, "step_pin"):
            continue
        step, direction = parse_pin(parser.get(section, "step_pin")), parse_pin(parser.get(section, "dir_pin"))
        if step.mcu != "mcu":
            continue
        step_mm = get.number(section, "rotation_distance") / (
            get.number(section, "full_steps_per_rotation", FULL_STEPS) * get.number(section, "microsteps"))
        steppers[section] = StepperPins(section, step.name, direction.inverted, step_mm)
    return steppers


def _travel(parser: configparser.RawConfigParser, get: _Getter, rail: str) -> tuple[float, float, float]:
    """(position_min, position_max, position_endstop) of a rail, with klippy's defaults."""
    low = get.number(rail, "position_min", 0.0)
    if parser.has_option(rail, "position_endstop"):  # klippy: position_max defaults to it (a delta's towers)
        at = get.number(rail, "position_endstop")
        return low, get.number(rail, "position_max", at), at
    high = get.number(rail, "position_max")  # an endstop at the end homing_positive_dir names
    return low, high, high if _homes_up(parser, rail) else low


# klippy/kinematics/*.py calc_position: a rail's coordinate as weights of its axes' steppers' positions (any
# other rail, and any other kinematics, is its own stepper's position: cartesian, a delta's tower carriages)
KINEMATICS: dict[str, dict[str, dict[str, float]]] = {
    "corexy": {"x": {"x": 0.5, "y": 0.5}, "y": {"x": 0.5, "y": -0.5}},
    "corexz": {"x": {"x": 0.5, "z": 0.5}, "z": {"x": 0.5, "z": -0.5}},
    "hybrid_corexy": {"x": {"x": 1.0, "y": 1.0}},
    "hybrid_corexz": {"x": {"x": 1.0, "z": 1.0}},
}


def _kinematics(parser: configparser.RawConfigParser) -> str:
    return parser.get("printer", "kinematics", fallback="cartesian").strip().lower()


def _terms(kinematics: str, section: str, steppers: dict[str, StepperPins]) -> tuple[tuple[StepperPins, float], ...]:
    """The steppers (with weights) whose positions make ``section``'s rail coordinate: the section itself
    for its own axis (stepper_x1 stands for stepper_x on its rail), the other axes' first steppers."""
    axis = re.sub(r"\d+$", "", section.removeprefix("stepper_"))
    weights = KINEMATICS.get(kinematics, {}).get(axis, {axis: 1.0})
    names = {other: section if other == axis else f"stepper_{other}" for other in weights}
    return tuple((steppers[names[other]], weight) for other, weight in weights.items() if names[other] in steppers)


def _probe(parser: configparser.RawConfigParser, get: _Getter) -> ProbePins | None:
    """The [bltouch] (else [probe]) whose sensor is on the main MCU, with the nozzle height through stepper_z."""
    for section, option in (("bltouch", "sensor_pin"), ("probe", "pin")):
        if not parser.has_option(section, option):
            continue
        sensor = parse_pin(parser.get(section, option))
        if sensor.mcu != "mcu":
            return None
        control = parse_pin(parser.get(section, "control_pin")).name if section == "bltouch" else None
        return ProbePins(section, sensor, control, get.number(section, "z_offset"), _z_rail(parser, get))
    return None


def _z_rail(parser: configparser.RawConfigParser, get: _Getter) -> RailPins | None:
    """The nozzle's height: stepper_z's rail through the kinematics (None on a delta, or without stepper_z)."""
    steppers = _steppers(parser, get)
    kinematics = _kinematics(parser)
    if kinematics == "delta" or "stepper_z" not in steppers:
        return None
    low = get.number("stepper_z", "position_min", 0.0)
    return RailPins(low, get.number("stepper_z", "position_max"), _terms(kinematics, "stepper_z", steppers))


def _rail(parser: configparser.RawConfigParser, section: str) -> str:
    """Where a stepper's positions are: its own section, else its rail's first (stepper_z1 -> stepper_z), else a
    delta's stepper_a (klippy's defaults for stepper_b and stepper_c)."""
    for candidate in (section, re.sub(r"\d+$", "", section), "stepper_a"):
        if parser.has_option(candidate, "position_endstop") or parser.has_option(candidate, "position_max"):
            return candidate
    return section


def _homes_up(parser: configparser.RawConfigParser, section: str) -> bool:
    return parser.get(section, "homing_positive_dir", fallback="").strip().lower() in ("true", "1")
