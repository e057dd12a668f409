"""Number types for argparse that need nothing but the standard library: finite, within a range, whole.
(tools/cli/args.py re-exports them; a CLI that must start fast, twin-klipper-mcu, imports them here.)"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def finite_float(text: str) -> float:
    """A finite number (not nan, not inf)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, not {text!r}")
    return value


def ranged_float(low: float, high: float, unit: str) -> Callable[[str], float]:
    """An argparse type: a finite number within low..high (unit, if any, for the message)."""

    def parse(text: str) -> float:
        value = finite_float(text)
        if not low <= value <= high:
            suffix = f" {unit}" if unit else ""
            raise argparse.ArgumentTypeError(f"{value:g}{suffix} is outside {low:g}..{high:g}{suffix}")
        return value

    return parse


def ranged_int(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: a whole number within low..high."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, not {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value} is outside {low}..{high}")
        return value

    return parse
