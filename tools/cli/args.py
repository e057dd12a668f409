"""Argument types shared by the CLIs: numbers that refuse NaN, infinities and out-of-range values, and a
checked plot path (the one-line parser is tools/entry.py's ``OneLineParser``)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path


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
    """An argparse type: a finite number within low..high (unit for the message)."""

    def parse(text: str) -> float:
        value = finite_float(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value:g} {unit} is outside {low:g}..{high:g} {unit}")
        return value

    return parse


def plot_path(text: str) -> Path:
    """A plot file whose folder exists and whose extension matplotlib can write: checked before any work."""
    path = Path(text)
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"the folder {str(path.parent)!r} does not exist")
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise argparse.ArgumentTypeError("plots need matplotlib: pip install '.[plot]'") from None
    formats = Figure().canvas.get_supported_filetypes()
    suffix = path.suffix.lstrip(".").lower()
    if suffix not in formats:
        raise argparse.ArgumentTypeError(f"unknown plot format {path.suffix or '(none)'!r}; give one of "
                                         f"{', '.join('.' + f for f in sorted(formats))}")
    return path
