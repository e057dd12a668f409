"""The twin MCU's data dictionary: the commands and responses it speaks, its pins, constants and
shutdown reasons, served to the host by ``identify`` as zlib-compressed JSON.

The format strings are those of klippy 0.12.0.dev276 (the host the tests run), which
``lookup_command`` compares character for character; they drift between Klipper versions
(``query_analog_in``'s ``range_check_count`` field, for one). Message ids are one byte
(klippy's parser takes tags -32..95 only): identify_response is 0 and identify 1, as
klippy/msgproto.py's DefaultMessages fix them; the rest are numbered from 2.
"""

from __future__ import annotations

import json
import zlib
from dataclasses import dataclass, field

from protocol.klipper_mcu.chip_temperature import TEMPERATURE_PIN, TEMPERATURE_PIN_NAME, chip_sensor
from protocol.klipper_mcu.codec import MessageFormat

# The heater-only board: an ATmega2560 as Klipper builds it (src/avr): 16 MHz timer, 10-bit ADC, 8-bit PWM.
CLOCK_FREQ = 16_000_000
ADC_MAX = 1023
PWM_MAX = 255
STATS_SUMSQ_BASE = 256  # src/basecmd.c SUMSQ_BASE
MOVE_COUNT = 1024  # src/basecmd.c move_finalize: the most queue slots alloc_chunks hands out
MCU_NAME = "heater-twin"
DEFAULT_SENSOR = "EPCOS 100K B57560G104F"  # the board's thermistors: config/generic-ramps.cfg, extruder and bed


@dataclass(frozen=True)
class Chip:
    """An MCU as Klipper builds it: its name (what --mcu and a config's "compiled for" say), its GPIO ports
    of ``port_pins`` pins each (src/avr/gpio.c GPIO(): PA0 = 0, 8 a port; src/stm32/internal.h: 16 a port),
    its ADC pins (src/avr/adc.c, src/stm32/adc.c adc_pins), its timer's CLOCK_FREQ, ADC_MAX and PWM_MAX
    (the hardware PWM's full scale) and its MCU constant (the Kconfig CONFIG_MCU string klippy shows)."""

    name: str
    ports: str
    adc_pins: tuple[str, ...]
    clock_freq: int = CLOCK_FREQ
    adc_max: int = ADC_MAX
    pwm_max: int = PWM_MAX
    port_pins: int = 8
    mcu: str = ""  # "" : the name
    buses: tuple[tuple[str, str, str], ...] = ()  # (spi_bus or i2c_bus, its name, BUS_PINS_<name>), numbered in order

    @property
    def mcu_constant(self) -> str:
        return self.mcu or self.name

    def bus_enumerations(self) -> dict[str, dict[str, int]]:
        """{"spi_bus": {name: number}, "i2c_bus": ...}: each kind's buses numbered in their order."""
        enumerations: dict[str, dict[str, int]] = {}
        for param, name, _ in self.buses:
            kind = enumerations.setdefault(param, {})
            kind[name] = len(kind)
        return enumerations

    def clocks(self, seconds: float) -> int:
        """A duration in this MCU's timer clocks."""
        return round(seconds * self.clock_freq)

    def pin_number(self, name: str) -> int:
        """The MCU's number of a pin name (PB4 -> 12 on an AVR, 20 on an STM32); ValueError if it has no
        such pin."""
        if len(name) in (3, 4) and name[0] == "P" and name[1] in self.ports and name[2:].isdigit():
            bit = int(name[2:])
            if bit < self.port_pins and name[2:] == str(bit):
                return (ord(name[1]) - ord("A")) * self.port_pins + bit
        raise ValueError(f"no pin {name!r} on the {self.name} (P<port><0-{self.port_pins - 1}>, ports "
                         f"{', '.join(self.ports)})")

    @property
    def has_temperature(self) -> bool:
        """Whether the chip reads its own temperature on ADC_TEMPERATURE (chip_temperature.py)."""
        return chip_sensor(self.mcu_constant) is not None

    def pin_name(self, number: int) -> str:
        if number == TEMPERATURE_PIN and self.has_temperature:
            return TEMPERATURE_PIN_NAME
        port, bit = divmod(number, self.port_pins)
        return f"P{chr(ord('A') + port)}{bit}"

    def has_pin(self, number: int) -> bool:
        """Whether a pin number is one of the chip's (src/avr/gpio.c: past the last port it is not)."""
        return (0 <= number < (ord(self.ports[-1]) - ord("A") + 1) * self.port_pins
                and chr(ord("A") + number // self.port_pins) in self.ports)


def _pins(spec: str) -> tuple[str, ...]:
    """Pin names from ranges: "PA0-7 PC4" -> PA0..PA7, PC4."""
    names: list[str] = []
    for part in spec.split():
        first, _, last = part.partition("-")
        names += [f"{first[:2]}{n}" for n in range(int(first[2:]), int(last or first[2:]) + 1)]
    return tuple(names)


def _buses(spi: str, i2c: str) -> tuple[tuple[str, str, str], ...]:
    """Bus enumerations from "name:PIN,PIN,PIN name:..." lists (src/avr/spi.c, i2c.c; src/stm32/spi.c, i2c.c)."""
    return tuple((param, *bus.split(":", 1)) for param, buses in (("spi_bus", spi), ("i2c_bus", i2c))  # type: ignore[misc]
                 for bus in buses.split())


STM32_SPI = "spi2:PB14,PB15,PB13 spi1:PA6,PA7,PA5 spi1a:PB4,PB5,PB3"
STM32_I2C = "i2c1:PB6,PB7 i2c1a:PB8,PB9 i2c2:PB10,PB11"
STM32_F4_SPI = STM32_SPI + " spi2a:PC2,PC3,PB10 spi3:PB4,PB5,PB3 spi3a:PC11,PC12,PC10"


def _stm32(name: str, mcu: str, clock_mhz: int, ports: str, adc: str = "PA0-7 PB0-1 PC0-5", spi: str = STM32_SPI,
           i2c: str = STM32_I2C) -> Chip:
    """An STM32 as src/stm32 builds it: 16 pins a port, a 12-bit ADC (ADC_MAX 4095) on ``adc``'s pins
    (src/stm32/adc.c, stm32f0_adc.c, stm32h7_adc.c adc_pins), hardware PWM to 1 << 15 (hard_pwm.c MAX_PWM), the
    SPI and I2C buses klippy 0.12's firmware names."""
    return Chip(name, ports, (*_pins(adc), TEMPERATURE_PIN_NAME), clock_freq=clock_mhz * 1_000_000, adc_max=4095,
                pwm_max=1 << 15, port_pins=16, mcu=mcu, buses=_buses(spi, i2c))


ATMEGA2560_PORTS = "ABCDEFGHJKL"
CHIPS = {chip.name: chip for chip in (
    Chip("atmega2560", ATMEGA2560_PORTS, _pins("PF0-7 PK0-7"), buses=_buses("spi:PB3,PB2,PB1", "twi:PD0,PD1")),
    Chip("atmega1284p", "ABCD", _pins("PA0-7"), buses=_buses("spi:PB6,PB5,PB7", "twi:PC0,PC1")),  # ADC0-7
    Chip("atmega644p", "ABCD", _pins("PA0-7"), buses=_buses("spi:PB6,PB5,PB7", "twi:PC0,PC1")),
    # src/stm32/Kconfig: CLOCK_FREQ (an external crystal) and MCU; the ports their CMSIS headers define
    _stm32("stm32f103", "stm32f103xe", 72, "ABCDEFG", spi=STM32_SPI + " spi3:PB4,PB5,PB3"),
    _stm32("stm32f070", "stm32f070xb", 48, "ABCDF"),
    _stm32("stm32f401", "stm32f401xc", 84, "ABCDEH", spi=STM32_F4_SPI + " spi4:PE13,PE14,PE12",
           i2c=STM32_I2C + " i2c3:PA8,PC9"),
    _stm32("stm32f407", "stm32f407xx", 168, "ABCDEFGHI", "PA0-7 PB0-1 PC0-5 PF3-10", STM32_F4_SPI + " spi2b:PI2,PI3,PI1",
           STM32_I2C + " i2c3:PA8,PC9 i2c2a:PH4,PH5 i2c3a:PH7,PH8"),
    _stm32("stm32f446", "stm32f446xx", 180, "ABCDEFGH", "PA0-7 PB0-1 PC0-5 PF3-10", STM32_F4_SPI + " spi4:PE13,PE14,PE12",
           STM32_I2C + " i2c3:PA8,PC9"),
    _stm32("stm32g0b1", "stm32g0b1xx", 64, "ABCDEF", "PA0-7 PB0-2 PB10-12 PC4-5"),
    _stm32("stm32h743", "stm32h743xx", 400, "ABCDEFGHIJK", "PA0-7 PB0-1 PC0-5 PF3-14 PH2-5"),
)}
BOARD_CHIP = Chip(MCU_NAME, ATMEGA2560_PORTS, CHIPS["atmega2560"].adc_pins)  # the heater-only board's
PORTS = BOARD_CHIP.ports
ADC_PINS = BOARD_CHIP.adc_pins

COMMANDS = (
    "identify offset=%u count=%c",
    "get_uptime",
    "get_clock",
    "get_config",
    "allocate_oids count=%c",
    "finalize_config crc=%u",
    "emergency_stop",
    "clear_shutdown",
    "reset",
    "config_reset",
    "debug_nop",
    "debug_read order=%c addr=%u",
    "config_analog_in oid=%c pin=%u",
    "query_analog_in oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u min_value=%hu"
    " max_value=%hu range_check_count=%c",
    "config_digital_out oid=%c pin=%u value=%c default_value=%c max_duration=%u",
    "set_digital_out_pwm_cycle oid=%c cycle_ticks=%u",
    "queue_digital_out oid=%c clock=%u on_ticks=%u",
    "update_digital_out oid=%c value=%c",
    "set_digital_out pin=%u value=%c",
    "config_pwm_out oid=%c pin=%u cycle_ticks=%u value=%hu default_value=%hu max_duration=%u",
    "queue_pwm_out oid=%c clock=%u value=%hu",
    "set_pwm_out pin=%u cycle_ticks=%u value=%hu",
)
RESPONSES = (
    "identify_response offset=%u data=%.*s",
    "uptime high=%u clock=%u",
    "clock clock=%u",
    "config is_config=%c crc=%u is_shutdown=%c move_count=%hu",
    "analog_in_state oid=%c next_clock=%u value=%hu",
    "shutdown clock=%u static_string_id=%hu",
    "is_shutdown static_string_id=%hu",
    "stats count=%u sum=%u sumsq=%u",
    "debug_result val=%u",
    "starting",
)
# Commands a shut-down MCU still runs (DECL_COMMAND_FLAGS(..., HF_IN_SHUTDOWN, ...)); the others
# are answered with is_shutdown.
IN_SHUTDOWN = frozenset({"identify", "get_uptime", "get_clock", "get_config", "emergency_stop", "clear_shutdown",
                         "reset", "config_reset", "debug_nop"})

# Shutdown reasons, worded as the C sources word them (klippy shows the text after "MCU 'mcu' shutdown: ").
COMMAND_REQUEST = "Command request"  # src/basecmd.c emergency_stop
ADC_OUT_OF_RANGE = "ADC out of range"  # src/adccmds.c
TIMER_TOO_CLOSE = "Timer too close"  # src/sched.c sched_add_timer
RESCHEDULED_IN_PAST = "Rescheduled timer in the past"  # src/avr/timer.c
MISSED_DIGITAL_OUT = "Missed scheduling of next digital out event"  # src/gpiocmds.c
DIGITAL_OUT_EXCEEDS = "Scheduled digital out event will exceed max_duration"
CYCLE_WHILE_PENDING = "Can not set soft pwm cycle ticks while updates pending"
UPDATE_WITH_QUEUE = "update_digital_out not valid with active queue"
MISSED_PWM = "Missed scheduling of next hard pwm event"  # src/pwmcmds.c
PWM_EXCEEDS = "Scheduled pwm event will exceed max_duration"
CLEARED_WHEN_NOT_SHUTDOWN = "Shutdown cleared when not shutdown"  # src/sched.c
CONFIG_RESET_NOT_SHUTDOWN = "config_reset only available when shutdown"  # src/basecmd.c
OIDS_ALLOCATED = "oids already allocated"
CANT_ASSIGN_OID = "Can't assign oid"
INVALID_OID = "Invalid oid type"
ALREADY_FINALIZED = "Already finalized"
MOVE_QUEUE_OVERFLOW = "Move queue overflow"
INVALID_COMMAND = "Invalid command"  # src/command.c
PARSER_ERROR = "Command parser error"
NOT_ADC_PIN = "Not a valid ADC pin"  # src/avr/adc.c
NOT_OUTPUT_PIN = "Not an output pin"  # src/avr/gpio.c
NOT_PWM_PIN = "Not a valid PWM pin"  # src/avr/hard_pwm.c
NOT_INPUT_PIN = "Not a valid input pin"  # src/avr/gpio.c
STEPPER_ACTIVE = "Can't reset time when stepper active"  # src/stepper.c
INVALID_COUNT = "Invalid count parameter"
STATIC_STRINGS = (COMMAND_REQUEST, ADC_OUT_OF_RANGE, TIMER_TOO_CLOSE, RESCHEDULED_IN_PAST, MISSED_DIGITAL_OUT,
                  DIGITAL_OUT_EXCEEDS, CYCLE_WHILE_PENDING, UPDATE_WITH_QUEUE, MISSED_PWM, PWM_EXCEEDS,
                  CLEARED_WHEN_NOT_SHUTDOWN, CONFIG_RESET_NOT_SHUTDOWN, OIDS_ALLOCATED, CANT_ASSIGN_OID, INVALID_OID,
                  ALREADY_FINALIZED, MOVE_QUEUE_OVERFLOW, INVALID_COMMAND, PARSER_ERROR, NOT_ADC_PIN,
                  NOT_OUTPUT_PIN, NOT_PWM_PIN, NOT_INPUT_PIN, STEPPER_ACTIVE, INVALID_COUNT)


class Shutdown(Exception):
    """src/sched.c shutdown(): unwinds the handler that called it."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def pin_number(name: str) -> int:
    """The heater-only board's number of a pin name (PB4 -> 12); ValueError if it has no such pin."""
    return BOARD_CHIP.pin_number(name)


def pin_name(number: int) -> str:
    return BOARD_CHIP.pin_name(number)


@dataclass(frozen=True)
class Dictionary:
    """The dictionary the MCU serves and parses by: formats by id and by name, static strings."""

    version: str
    chip: Chip = BOARD_CHIP
    commands: dict[str, MessageFormat] = field(default_factory=dict)  # by name
    responses: dict[str, MessageFormat] = field(default_factory=dict)
    static_string_ids: dict[str, int] = field(default_factory=dict)

    @property
    def by_id(self) -> dict[int, MessageFormat]:
        """The commands by message id (what the MCU parses)."""
        return {fmt.msg_id: fmt for fmt in self.commands.values()}

    def data(self) -> bytes:
        """The compressed JSON that ``identify`` serves."""
        doc = {
            "version": self.version,
            "build_versions": "heater-twin klippy-0.12 command set",
            "commands": {fmt.text: fmt.msg_id for fmt in self.commands.values()},
            "responses": {fmt.text: fmt.msg_id for fmt in self.responses.values()},
            "output": {},
            "enumerations": {
                "pin": {**{f"P{port}0": [self.chip.pin_number(f"P{port}0"), self.chip.port_pins]
                           for port in self.chip.ports},
                        **({TEMPERATURE_PIN_NAME: TEMPERATURE_PIN} if self.chip.has_temperature else {})},
                "static_string_id": self.static_string_ids,
                **self.chip.bus_enumerations(),
            },
            "config": {"CLOCK_FREQ": self.chip.clock_freq, "MCU": self.chip.mcu_constant, "ADC_MAX": self.chip.adc_max,
                       "PWM_MAX": self.chip.pwm_max, "STATS_SUMSQ_BASE": STATS_SUMSQ_BASE,
                       **{f"BUS_PINS_{name}": pins for _, name, pins in self.chip.buses}},
        }
        return zlib.compress(json.dumps(doc, sort_keys=True).encode())


def build_dictionary(version: str, chip: Chip = BOARD_CHIP, families: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = ()
                     ) -> Dictionary:
    """The twin MCU's dictionary: identify_response 0, identify 1, then the rest in order; ``families``:
    (commands, responses) beyond the heater board's (a printer.cfg's steppers, endstops, display)."""
    commands = COMMANDS + tuple(c for family, _ in families for c in family)
    responses = RESPONSES + tuple(r for _, family in families for r in family)
    texts = [responses[0], commands[0], *commands[1:], *responses[1:]]
    formats = {text: MessageFormat(text, msg_id) for msg_id, text in enumerate(texts)}
    return Dictionary(
        version=version, chip=chip,
        commands={formats[t].name: formats[t] for t in commands},
        responses={formats[t].name: formats[t] for t in responses},
        static_string_ids={text: number for number, text in enumerate(STATIC_STRINGS, start=1)},
    )
