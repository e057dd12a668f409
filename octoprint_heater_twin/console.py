"""Marlin's console text as the plugin reads and writes it: the M303 command, its end, the PID gains in
an M301/M304 line (what M503 reports, what Apply sends), and a capture in OctoPrint's terminal form.

Only Marlin G-code: the plugin speaks to twin-serial and to a real Marlin printer alike.
"""

from __future__ import annotations

import re
from typing import NamedTuple

HEATERS = {"extruder": ("M301", "E0"), "heater_bed": ("M304", "E-1")}  # heater: (its gains command, M303's E)
MIN_CYCLES = 3  # Marlin's M303 prints Ku/Tu and gains from its third cycle on (temperature.cpp, PID_autotune)
MAX_CYCLES = 20  # the top of M303's C range: Marlin clamps C to 3..20, so C25 would run 20 and say nothing
# Text as a terminal shows it: no NUL or other control character but tab and line ends, and no U+FFFD (what a
# browser reads where a file's bytes are not UTF-8). A binary file uploaded as a capture has them.
NOT_TEXT_RE = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffd]")
# An M301/M304 line: M503's "echo:  M301 P22.20 I1.08 D114.00", the command Apply sends "M301 E0 P.. I.. D..";
# builds with PID_EXTRUSION_SCALING or PID_FAN_SCALING print C and F after D.
GAINS_RE = re.compile(r"\b(M30[14])(?:\s+E0)?\s+P([-+]?[\d.]+)\s+I([-+]?[\d.]+)\s+D([-+]?[\d.]+)")
FINISHED = "PID Autotune finished"  # Marlin's STR_PID_AUTOTUNE_FINISHED starts so
FAILED = "PID Autotune failed"  # STR_PID_AUTOTUNE ... (" Bad heater id", " Temperature too high", " timeout")
ERROR_PREFIX = "Error:"  # a kill (thermal runaway during the cycles) or a refused command
# The printer objecting to a command: "Error:...", "echo:Error writing to EEPROM!", "echo:Unknown command: ...",
# the twin's "echo:M301 refused: ..."
COMPLAINT_RE = re.compile(r"Error|Unknown command|refused")
# M503 prints two decimals: a stored gain reads back within half of the last digit, plus float32's rounding
# of the scaled gain Marlin keeps (Ki * dt, Kd / dt): a relative 2^-23 or so, taken as 1e-6.
READBACK_ABS = 0.005
READBACK_REL = 1e-6
# Marlin's report during M303, every REPORT_INTERVAL_S: " T:201.37 /0.00 B:24.97 /0.00 @:127 B@:0"; the heater's
# temperature and its power, soft PWM 0..POWER_FULL (the PID's 0..255 output halved: 127 is full power).
READING_RES = {"extruder": (re.compile(r"(?<![\w@])T:\s*(-?[\d.]+)"), re.compile(r"(?<![\w@])@:\s*(\d+)")),
               "heater_bed": (re.compile(r"(?<![\w@])B:\s*(-?[\d.]+)"), re.compile(r"(?<![\w@])B@:\s*(\d+)"))}
REPORT_INTERVAL_S = 2.0  # Marlin's PID_autotune prints the heaters' states every 2 s
POWER_FULL = 127
# Each relay cycle past the first swing prints its bias (" bias: 82 d: 82 min: 207.03 max: 216.78"): C lines for C8
BIAS_RE = re.compile(r"\bbias:\s*-?\d")


class Gains(NamedTuple):
    """PID gains in Marlin's M301/M304 units."""

    kp: float
    ki: float
    kd: float

    def flag(self) -> str:
        """twin-tune's --current-gains value."""
        return f"{self.kp:g},{self.ki:g},{self.kd:g}"

    def text(self) -> str:
        return f"P{self.kp:g} I{self.ki:g} D{self.kd:g}"

    def command(self, heater: str) -> str:
        """What Apply sends for these gains: ``M301 E0 P.. I.. D..`` (the hotend) or ``M304 P.. I.. D..``."""
        code = HEATERS[heater][0]
        return f"{code} E0 {self.text()}" if heater == "extruder" else f"{code} {self.text()}"

    def holds(self, read: Gains) -> bool:
        """Whether ``read`` (M503's report) is these gains as the printer prints them."""
        return all(abs(r - s) <= READBACK_ABS + READBACK_REL * abs(s) for s, r in zip(self, read))


def autotune_command(heater: str, target_c: float, cycles: int) -> str:
    """``M303 E0 S210 C8`` (``E-1`` for the bed)."""
    return f"M303 {HEATERS[heater][1]} S{target_c:g} C{cycles}"


def gains_in(text: str, heater: str) -> Gains | None:
    """The gains an M301 (extruder) or M304 (heater_bed) line states, else None."""
    m = GAINS_RE.search(text)
    if m is None or m[1] != HEATERS[heater][0]:
        return None
    return Gains(float(m[2]), float(m[3]), float(m[4]))


def last_gains(lines: list[str], heater: str) -> Gains | None:
    """The last gains of ``heater`` among ``lines`` (M503's report, or a pasted capture with it)."""
    found = [g for g in (gains_in(line, heater) for line in lines) if g is not None]
    return found[-1] if found else None


def reading(line: str, heater: str) -> tuple[float, float] | None:
    """The heater's temperature (C) and power (% of full) in a report line of M303's, else None."""
    temp_re, power_re = READING_RES[heater]
    temp, power = temp_re.search(line), power_re.search(line)
    if temp is None or power is None:
        return None
    return float(temp[1]), 100.0 * min(int(power[1]), POWER_FULL) / POWER_FULL


def is_cycle_end(line: str) -> bool:
    """Whether the line ends one of M303's relay cycles (its bias line)."""
    return BIAS_RE.search(line) is not None


def is_text(capture: str) -> bool:
    """Whether ``capture`` is console text (a binary file is not)."""
    return NOT_TEXT_RE.search(capture) is None


def is_complaint(line: str) -> bool:
    return COMPLAINT_RE.search(line) is not None


def is_ok(line: str) -> bool:
    """Marlin's acknowledgement of the command it ran ("ok", or "ok T:..." with a temperature report)."""
    return line.startswith("ok")


def sent(command: str) -> str:
    return f"Send: {command}"


def received(line: str) -> str:
    """A line from the printer as OctoPrint's terminal shows it (tools/logs reads the prefix)."""
    return f"Recv: {line.rstrip()}"
