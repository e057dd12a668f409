"""The per-reading laws built for the AVR: each one's C build, its records, and the Python port it mirrors.

A law's records mirror the C structs of its glue file (harness/glue_*.c), packed and
little-endian as avr-gcc lays them out: ``law_in`` (the first byte the operation), ``law_out``,
``law_state`` and ``law_config``. The Python side of a law makes the port object (the class in
firmware_port/ the C mirrors), reads its configuration and state as the same tuples, and steps
it on an input record, so both sides can be compared field by field after every step.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from firmware_port.avr.build import ElfSpec
from firmware_port.fuzzy_pi import SEED004_HOTEND, FuzzyPi, FuzzyPiConfig
from firmware_port.fuzzy_pid import SEED001_BOARD, FuzzyPid, FuzzyPidConfig
from firmware_port.marlin.adc import AdcSequencer
from firmware_port.marlin.bangbang import BangBangBed, BangBangHotend
from firmware_port.marlin.constants import TICKS_PER_READING
from firmware_port.marlin.pid import HOTEND_GAINS, PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND, PidFixed, PidGains
from firmware_port.marlin.softpwm import SoftPwm
from firmware_port.thermistor import B3950_TABLE

OP_STEP, OP_RESET, OP_INIT = 0, 1, 2  # harness/harness.h
Fields = tuple[tuple[str, str], ...]  # (name, numpy format), in C struct order


class UnknownBuild(ValueError):
    """A controller the user asked to run on the AVR that has no C build: their input, not a bug."""


class Law:
    """A law as the harness runs it; subclasses say what the C is and how the Python port steps."""

    name: str
    title: str  # one line for the report
    spec: ElfSpec
    period_isrs: int = TICKS_PER_READING  # how often Marlin calls it: once a reading (per heater), or every ISR
    in_fields: Fields
    out_fields: Fields = ()
    state_fields: Fields = ()
    config_fields: Fields = ()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}: {self.title})"

    @property
    def record_fields(self) -> Fields:
        """What the harness reads after each step: law_out, then law_state."""
        return self.out_fields + self.state_fields

    @property
    def init_record(self) -> tuple:
        """The input record of a power-up (OP_INIT)."""
        return (OP_INIT,) + (0,) * (len(self.in_fields) - 1)

    @property
    def symbols(self) -> tuple[str, ...]:
        """The SRAM symbols that make up the record, in order."""
        return tuple(s for s, f in (("law_out", self.out_fields), ("law_state", self.state_fields)) if f)

    def port(self, settings: Any = None) -> Any:
        """A fresh Python port object, as the board constructs it."""
        raise NotImplementedError

    def step(self, port: Any, record: tuple) -> tuple:
        """Run the port on one input record (op OP_STEP); its outputs as law_out's fields."""
        raise NotImplementedError

    def config(self, port: Any) -> tuple:
        """The port's configuration as law_config's fields (the Q integers its settings became)."""
        return ()

    def state(self, port: Any) -> tuple:
        """The port's state as law_state's fields."""
        return ()


class ControllerLaw(Law):
    """A controller: a reading and a target in (law_in is harness.h's reading_in_t), its output
    first in law_out (``out_frac_bits`` below the 0..255 scale), built from ``port_type``."""

    in_fields = (("op", "u1"), ("temp_q5", "<i2"), ("target_c", "<i2"))
    out_fields: Fields = (("out", "u1"),)
    out_frac_bits = 0
    port_type: type

    def step(self, port: Any, record: tuple) -> tuple:
        return (port.update(record[1], record[2], 0),)

    def counts(self, record: tuple) -> int:
        """The output on the 0..255 scale from a record."""
        return record[0] >> self.out_frac_bits

    def mirrors(self, port: Any) -> bool:
        """Whether this law's C is the build of this Python controller, with its compile-time options."""
        return type(port) is self.port_type


class PidLaw(ControllerLaw):
    """firmware_port/marlin/pid.py PidFixed; Marlin's previous-temperature update is a compile-time option."""

    port_type = PidFixed
    out_fields = (("out_q8", "<i4"),)
    out_frac_bits = 8
    state_fields = (("i_sum_q5", "<i4"), ("d_term_q8", "<i4"), ("prev_q5", "<i2"), ("reset_pending", "u1"))
    config_fields = (("kp_q12", "<i4"), ("ki_q24", "<i4"), ("kd_q16", "<i4"), ("i_max_q5", "<i4"))

    def __init__(self, prev_temp_mode: str):
        self.mode = prev_temp_mode
        in_band = prev_temp_mode == PREV_TEMP_IN_BAND
        self.name = "pid_in_band" if in_band else "pid"
        where = "in band only (Marlin 2.1.x)" if in_band else "every call (Marlin 2.0.x)"
        self.title = f"PID fixed point, T_prev {where}"
        self.spec = ElfSpec("glue_pid.c", ("pid.c",), (f"PID_PREV_TEMP_IN_BAND={int(in_band)}",))

    def port(self, settings: PidGains | None = None) -> PidFixed:
        return PidFixed(settings or HOTEND_GAINS, self.mode)

    def step(self, port: PidFixed, record: tuple) -> tuple:
        return (port.update_q8(record[1], record[2]),)

    def config(self, port: PidFixed) -> tuple:
        return port.kp_q12, port.ki_q24, port.kd_q16, port.i_max_q5

    def state(self, port: PidFixed) -> tuple:
        return port.i_sum_q5, port.d_term_q8, port.prev_q5, int(port.reset_pending)

    def mirrors(self, port: Any) -> bool:
        return super().mirrors(port) and port.prev_temp_mode == self.mode


class BangBangHotendLaw(ControllerLaw):
    """firmware_port/marlin/bangbang.py BangBangHotend: stateless."""

    name = "bangbang_hotend"
    title = "bang-bang hotend"
    spec = ElfSpec("glue_bangbang_hotend.c", ("bangbang.c",))
    port_type = BangBangHotend

    def port(self, settings: None = None) -> BangBangHotend:
        return BangBangHotend()


class BangBangBedLaw(ControllerLaw):
    """firmware_port/marlin/bangbang.py BangBangBed; BED_LIMIT_SWITCHING is a compile-time option."""

    port_type = BangBangBed
    state_fields = (("output", "u1"),)

    def __init__(self, limit_switching: bool):
        self.limit_switching = limit_switching
        self.name = "bangbang_bed_limit" if limit_switching else "bangbang_bed"
        self.title = "bang-bang bed" + (", BED_LIMIT_SWITCHING" if limit_switching else "")
        self.spec = ElfSpec("glue_bangbang_bed.c", ("bangbang.c",), (f"BED_LIMIT_SWITCHING={int(limit_switching)}",))

    def port(self, settings: None = None) -> BangBangBed:
        return BangBangBed(self.limit_switching)

    def state(self, port: BangBangBed) -> tuple:
        return (port.output,)

    def mirrors(self, port: Any) -> bool:
        return super().mirrors(port) and port.limit_switching == self.limit_switching


class FuzzyPiLaw(ControllerLaw):
    """firmware_port/fuzzy_pi.py FuzzyPi: seed 004's fuzzy-like PI."""

    name = "fuzzy_pi"
    title = "fuzzy-like PI (seed 004)"
    spec = ElfSpec("glue_fuzzy_pi.c", ("fuzzy_pi.c",))
    port_type = FuzzyPi
    state_fields = (("duty_q16", "<i4"), ("err_prev_q5", "<i4"), ("have_prev", "u1"))
    config_fields = (("n_sets", "u1"), ("err_range_q5", "<i2"), ("derr_range_q5", "<i2"), ("du_range_q4", "<i2"),
                     ("out_max", "u1"))

    def port(self, settings: FuzzyPiConfig | None = None) -> FuzzyPi:
        return FuzzyPi(settings or SEED004_HOTEND)

    def config(self, port: FuzzyPi) -> tuple:
        return port.n_sets, port.err_range_q5, port.derr_range_q5, port.du_range_q4, port.out_max

    def state(self, port: FuzzyPi) -> tuple:
        return port.duty_q16, port.err_prev_q5, port.have_prev


class FuzzyPidLaw(ControllerLaw):
    """firmware_port/fuzzy_pid.py FuzzyPid: seed 001's fuzzy-PID; law_out also carries the gain factors."""

    name = "fuzzy_pid"
    title = "fuzzy-PID (seed 001)"
    spec = ElfSpec("glue_fuzzy_pid.c", ("fuzzy_pid.c",))
    port_type = FuzzyPid
    out_fields = (("out_q8", "<i4"), ("f_p_q12", "<i2"), ("f_i_q12", "<i2"), ("f_d_q12", "<i2"))
    out_frac_bits = 8
    state_fields = (("i_q8", "<i4"), ("e_prev_q5", "<i2"), ("have_prev", "u1"))
    config_fields = (("ke_q12", "<u4"), ("kec_ps_q12", "<u4"), ("span_q4", "u1"), ("literal", "u1"),
                     ("kp_q12", "<i4"), ("ki_q24", "<i4"), ("kd_q16", "<i4"))

    def port(self, settings: tuple[PidGains, FuzzyPidConfig] | None = None) -> FuzzyPid:
        gains, config = settings or (HOTEND_GAINS, SEED001_BOARD)
        return FuzzyPid(gains, config)

    def step(self, port: FuzzyPid, record: tuple) -> tuple:
        return (port.update_q8(record[1], record[2]), *port.factors_q12)

    def config(self, port: FuzzyPid) -> tuple:
        k = port.k
        return k.ke_q12, k.kec_ps_q12, k.span_q4, int(port.literal), k.kp_q12, k.ki_q24, k.kd_q16

    def state(self, port: FuzzyPid) -> tuple:
        return port.i_q8, port.e_prev_q5, port.have_prev


class ThermistorLaw(Law):
    """firmware_port/thermistor.py TempTable.lookup_q5 on B3950_TABLE: stateless."""

    name = "thermistor"
    title = f"B3950 table lookup ({len(B3950_TABLE.raw)} rows in PROGMEM) + interpolation"
    spec = ElfSpec("glue_thermistor.c", ("thermistor.c",))
    in_fields = (("op", "u1"), ("raw", "<i2"))
    out_fields = (("temp_q5", "<i2"),)

    def port(self, settings: None = None) -> Any:
        return B3950_TABLE

    def step(self, port: Any, record: tuple) -> tuple:
        return (port.lookup_q5(record[1]),)


class _ListPort:
    """An AdcPort that hands out the conversions of the current step."""

    def __init__(self) -> None:
        self.conversion = (0, 0)

    def sample(self, channel: int) -> int:
        return self.conversion[channel]


class AdcLaw(Law):
    """firmware_port/marlin/adc.py AdcSequencer.tick for a hotend and a bed: the x16 oversampled sums.

    A step is one ISR; ``take`` first clears raw_ready, as the main loop does when it reads them.
    """

    name = "adc"
    title = "ADC x16 oversampled sums (ISR step, 2 channels)"
    period_isrs = 1
    spec = ElfSpec("glue_adc.c", ("adc.c",))
    in_fields = (("op", "u1"), ("take", "u1"), ("conversion0", "<u2"), ("conversion1", "<u2"))
    state_fields = (("phase", "u1"), ("temp_count", "u1"), ("acc0", "<u2"), ("acc1", "<u2"), ("raw0", "<u2"),
                    ("raw1", "<u2"), ("raw_ready", "u1"))

    def port(self, settings: None = None) -> AdcSequencer:
        return AdcSequencer(2, _ListPort())

    def step(self, port: AdcSequencer, record: tuple) -> tuple:
        if record[1]:
            port.raw_ready = False
        assert isinstance(port.port, _ListPort)
        port.port.conversion = record[2:4]
        port.tick()
        return ()

    def state(self, port: AdcSequencer) -> tuple:
        return (port.phase, port.temp_count, *port.acc, *port.raw, int(port.raw_ready))


class SoftPwmLaw(Law):
    """firmware_port/marlin/softpwm.py SoftPwm.tick for a hotend and a bed.

    A step is one ISR, after the main loop has written the amounts flagged in ``write`` (bit ch).
    """

    name = "softpwm"
    title = "soft PWM (ISR step, 2 channels)"
    period_isrs = 1
    spec = ElfSpec("glue_softpwm.c", ("softpwm.c",))
    in_fields = (("op", "u1"), ("write", "u1"), ("amount0", "u1"), ("amount1", "u1"))
    out_fields = (("pins", "u1"),)
    state_fields = (("pwm_count", "u1"), ("amount0", "u1"), ("amount1", "u1"), ("count0", "u1"), ("count1", "u1"),
                    ("pin_bits", "u1"))

    def port(self, settings: None = None) -> SoftPwm:
        return SoftPwm(2)

    def step(self, port: SoftPwm, record: tuple) -> tuple:
        for channel in (0, 1):
            if record[1] >> channel & 1:
                port.set_amount(channel, record[2 + channel])
        port.tick()
        return (self._pins(port),)

    def state(self, port: SoftPwm) -> tuple:
        return (port.pwm_count, *port.amount, *port.count, self._pins(port))

    @staticmethod
    def _pins(port: SoftPwm) -> int:
        return sum(int(pin) << channel for channel, pin in enumerate(port.pins))


BASELINE = ElfSpec("glue_none.c", ())  # the empty board: flash and cycles are measured against it
LAWS: dict[str, Law] = {law.name: law for law in (
    PidLaw(PREV_TEMP_EVERY_SAMPLE),
    PidLaw(PREV_TEMP_IN_BAND),
    BangBangHotendLaw(),
    BangBangBedLaw(False),
    BangBangBedLaw(True),
    FuzzyPiLaw(),
    FuzzyPidLaw(),
    ThermistorLaw(),
    AdcLaw(),
    SoftPwmLaw(),
)}


def dtype(fields: Fields) -> np.dtype:
    """The packed record of a C struct."""
    return np.dtype(list(fields))


def law_for(controller: Any) -> ControllerLaw:
    """The law whose C build mirrors a Python controller; ValueError if it has none."""
    laws = [law for law in LAWS.values() if isinstance(law, ControllerLaw)]
    for law in laws:
        if law.mirrors(controller):
            return law
    names = sorted({law.port_type.__name__ for law in laws})
    raise UnknownBuild(f"{type(controller).__name__} has no AVR build (controllers with one: {', '.join(names)})")
