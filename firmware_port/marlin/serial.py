"""What the firmware prints: Arduino's float printing and the serial output sink."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

_F32 = np.float32
PRINT_FLOAT_MAX = 4294967040.0  # Print::printFloat's "ovf" bound ("determined empirically" there)


def format_float(value: float | np.floating, digits: int = 2) -> str:
    """Arduino ``Print::printFloat`` in float32 (avr-gcc's double), as Marlin's SERIAL_ECHO prints.

    The rounding constant 0.5/10**digits is added in float32, the integer part printed, then each
    digit taken from the float32 remainder; this is not always Python's round-half-even.
    """
    number = _F32(value)
    if np.isnan(number):
        return "nan"
    if np.isinf(number):
        return "inf"
    if abs(number) > PRINT_FLOAT_MAX:  # Arduino's guard: the integer part is an unsigned long
        return "ovf"
    out = ""
    if number < 0:
        out = "-"
        number = -number
    rounding = _F32(0.5)
    for _ in range(digits):
        rounding = _F32(rounding / _F32(10.0))
    number = _F32(number + rounding)
    int_part = int(number)
    out += str(int_part)
    if digits > 0:
        out += "."
    remainder = _F32(number - _F32(int_part))
    for _ in range(digits):
        remainder = _F32(remainder * _F32(10.0))
        digit = int(remainder)
        out += str(digit)
        remainder = _F32(remainder - _F32(digit))
    return out


class Console:
    """The board's serial TX: text exactly as written, newlines included.

    Marlin sometimes writes half a line (M303's bias lines) and finishes it later, so the sink
    keeps raw text; ``lines()`` splits what has been completed.
    """

    def __init__(self) -> None:
        self.text = ""
        self.listeners: list[Callable[[str], None]] = []  # callables(text) told of every write (the twin's trace, a transport)

    def __repr__(self) -> str:
        lines = self.lines()
        return f"Console({len(lines)} lines, last {lines[-1]!r})" if lines else "Console(empty)"

    def write(self, text: str) -> None:
        self.text += text
        for listener in self.listeners:
            listener(text)

    def writeln(self, text: str = "") -> None:
        self.write(text + "\n")

    def lines(self) -> list[str]:
        """Completed lines written so far (a trailing partial line is left out)."""
        return self.text.split("\n")[:-1]
