"""Marlin 2.1's G-code parser (gcode/parser.cpp, parser.h): one queued line in, one command out.

The parser follows the stock configuration: FASTER_GCODE_PARSER on (parameters are the letters
A-Z, the last occurrence of a letter wins), GCODE_CASE_INSENSITIVE off (``g1`` is not a command,
``x10`` is not a parameter), GCODE_QUOTED_STRINGS and TEMPERATURE_UNITS_SUPPORT off. Subcodes
(``G92.1``) are read as with USE_GCODE_SUBCODES, which only the CNC and probing options turn on;
no heater command has one.

Values keep C's prefix semantics: ``S210abc`` reads 210 and ``S`` alone is a flag without a
value. Integers go through avr-libc's 32-bit ``strtol``; floats are rounded to float32, the
only float avr-gcc has.
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass

from firmware_port.fixed import INT32_MAX, UINT32_MAX, clamp, sat_s32, wrap_s16, wrap_u8, wrap_u16, wrap_u32

STR_UNKNOWN_COMMAND = 'Unknown command: "'  # core/language.h
ECHO_START = "echo:"  # core/serial.cpp serial_echo_start()
COMMAND_LETTERS = "GMT"  # parser.cpp: "G, M, and T are always accepted"
STRING_ARG_M_CODES = frozenset((23, 28, 30, 117, 118, 928))  # parse(): the rest is one string
C_SPACE = " \t\n\v\f\r"  # isspace() in the C locale, what strtol skips
DIGITS = "0123456789"  # macros.h NUMERIC()
DECIMAL_SIGNED = DIGITS + ".-+"  # macros.h DECIMAL_SIGNED(): a value's characters
_FLOAT_PREFIX = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)")


def strtol(text: str) -> int:
    """C ``strtol(text, nullptr, 10)`` with AVR's 32-bit long: 0 without digits, saturating."""
    i, n = 0, len(text)
    while i < n and text[i] in C_SPACE:
        i += 1
    sign = -1 if i < n and text[i] == "-" else 1
    if i < n and text[i] in "+-":
        i += 1
    j = i
    while j < n and text[j] in DIGITS:
        j += 1
    digits = text[i:j].lstrip("0") or "0"
    if len(digits) > len(str(INT32_MAX)):  # also keeps int() clear of its digit limit
        return sat_s32(sign * (INT32_MAX + 1))
    return sat_s32(sign * int(digits))


def strtoul(text: str) -> int:
    """C ``strtoul(text, nullptr, 10)`` with a 32-bit unsigned long: a minus sign negates modulo
    2^32, beyond ULONG_MAX it saturates."""
    body = text.lstrip(C_SPACE)
    negative = body.startswith("-")
    digits = body[1:] if body[:1] in "+-" else body
    j = 0
    while j < len(digits) and digits[j] in DIGITS:
        j += 1
    magnitude = digits[:j].lstrip("0") or "0"
    if len(magnitude) > len(str(UINT32_MAX)) or int(magnitude) > UINT32_MAX:
        return UINT32_MAX
    return wrap_u32(-int(magnitude)) if negative else int(magnitude)


def float_to_u32(x: float) -> int:
    """A float cast to uint32_t (millis_t). C leaves out-of-range casts undefined; the twin
    saturates (NaN and negatives to 0, beyond 2^32 - 1 to 2^32 - 1), so the result is a uint32
    as Marlin's type says, whatever the value."""
    if not x > 0:
        return 0
    return UINT32_MAX if x >= UINT32_MAX else int(x)


def float32(x: float) -> float:
    """Round to the nearest float32 (avr-gcc's float and double); out of range gives +-inf."""
    try:
        return struct.unpack("<f", struct.pack("<f", x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)


def _valid_float(text: str, i: int) -> bool:
    """parser.h valid_float(): ``[-+]?.?[0-9]`` starts at ``text[i]``."""
    if text[i : i + 1] in ("-", "+"):
        i += 1
    if text[i : i + 1] == ".":
        i += 1
    return i < len(text) and text[i] in DIGITS


@dataclass(frozen=True)
class Command:
    """A parsed line: what GCodeParser holds after parse()."""

    letter: str  # 'G', 'M' or 'T'; '' when Marlin sees no command (its command_letter '?')
    code: int | None  # codenum, uint16_t
    subcode: int | None  # the digits after '.', uint8_t; None without a '.'
    params: dict[str, str]  # letter A-Z -> its value text, '' for a flag without a value
    text: str  # command_ptr: from the letter on, '*' and the spaces before it cut

    def has(self, letter: str) -> bool:
        """parser.seen(letter)."""
        return letter in self.params

    def has_value(self, letter: str) -> bool:
        """parser.seenval(letter): seen with a value."""
        return bool(self.params.get(letter))

    def value_ulong(self, letter: str, default: int = 0) -> int:
        """parser.value_ulong() (value_millis()): the 32-bit strtoul, or ``default``."""
        raw = self.params.get(letter)
        return strtoul(raw) if raw else default

    def value_byte(self, letter: str, default: int = 0) -> int:
        """parser.value_byte() / byteval(): strtol clamped to 0..255, or ``default`` without a value."""
        raw = self.params.get(letter)
        return clamp(strtol(raw), 0, 255) if raw else default

    def value_long(self, letter: str, default: int = 0) -> int:
        """parser.longval(): the 32-bit strtol (M110 N, times), or ``default`` without a value."""
        raw = self.params.get(letter)
        return strtol(raw) if raw else default

    def value_int(self, letter: str, default: int = 0) -> int:
        """parser.intval(): value_long() cast to int16_t, or ``default`` without a value."""
        return wrap_s16(self.value_long(letter)) if self.params.get(letter) else default

    def value_float(self, letter: str, default: float = 0.0) -> float:
        """parser.floatval(): the value's prefix as float32, or ``default`` without a value."""
        raw = self.params.get(letter)
        if not raw:
            return default
        prefix = _FLOAT_PREFIX.match(raw)  # a stored value is a valid float's text, so it has one
        return float32(float(prefix[0])) if prefix else 0.0

    def value_bool(self, letter: str, default: bool = False) -> bool:
        """parser.boolval(): seen, and either no value or a value_byte() (strtol clamped to
        0..255) that is not 0, so ``S-1`` and ``S0.5`` are false."""
        if letter not in self.params:
            return default
        raw = self.params[letter]
        return not raw or clamp(strtol(raw), 0, 255) != 0

    def value_celsius(self, letter: str, default: int = 0) -> int:
        """parser.celsiusval(): value_int() when TEMPERATURE_UNITS_SUPPORT is off."""
        return self.value_int(letter, default)


def _skip(s: str, i: int, chars: str) -> int:
    """The first index at or after ``i`` whose character is not in ``chars`` (the C string's
    terminating NUL never is)."""
    while i < len(s) and s[i] in chars:
        i += 1
    return i


def _after_line_number(s: str) -> int:
    """Skip leading spaces, then ``N[-+0-9][0-9]*`` and the spaces after it."""
    i = _skip(s, 0, " ")
    if s[i:i + 1] == "N" and s[i + 1:i + 2] and s[i + 1] in DIGITS + "-+":
        i = _skip(s, _skip(s, i + 2, DIGITS), " ")
    return i


def _without_checksum(s: str, from_index: int) -> str:
    """The line cut at its ``*`` (and the spaces before it), as Marlin nullifies them."""
    star = s.find("*", from_index)
    if star >= 0:
        while s[star - 1] == " ":
            star -= 1
        s = s[:star]
    return s


def _read_number(s: str, i: int, wrap) -> tuple[int, int]:
    """Decimal digits from ``i`` accumulated with the C type's wrap; (value, next index)."""
    value = 0
    while i < len(s) and s[i] in DIGITS:
        value = wrap(value * 10 + int(s[i]))
        i += 1
    return value, i


def _read_params(s: str, i: int) -> dict[str, str]:
    """Each parameter letter with its value text (only a valid float prefix is a value)."""
    params: dict[str, str] = {}
    while i < len(s):
        param = s[i]
        i += 1
        if "A" <= param <= "Z":
            i = _skip(s, i, " ")
            end = _skip(s, i, DECIMAL_SIGNED) if _valid_float(s, i) else i
            params[param] = s[i:end]
        if not (i < len(s) and "A" <= s[i] <= "Z"):  # skip the value, then spaces, to the next letter
            i = _skip(s, _skip(s, i, DECIMAL_SIGNED), " ")
    return params


def parse(line_text: str) -> Command:
    """GCodeParser::parse() on one queued line (with its ``N..`` and ``*cs``, as enqueued)."""
    s = line_text.split("\0", 1)[0]  # the C string ends at the first NUL
    start = _after_line_number(s)
    letter = s[start] if start < len(s) else "\0"
    if letter != "\0":
        s = _without_checksum(s, start + 1)
    text = s[start:]
    i = _skip(s, start + 1, " ")
    if letter not in COMMAND_LETTERS or not (i < len(s) and s[i] in DIGITS):
        return Command("", None, None, {}, text)
    code, i = _read_number(s, i, wrap_u16)
    subcode = None
    if s[i:i + 1] == ".":
        subcode, i = _read_number(s, i + 1, wrap_u8)
    i = _skip(s, i, " ")
    if letter == "M" and code in STRING_ARG_M_CODES:
        return Command(letter, code, subcode, {}, text)
    return Command(letter, code, subcode, _read_params(s, i), text)


def unknown_command_text(cmd: Command) -> str:
    """parser.unknown_command_warning(): the reply line, newline included."""
    return f'{ECHO_START}{STR_UNKNOWN_COMMAND}{cmd.text}"\n'
