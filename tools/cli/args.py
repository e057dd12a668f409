"""Argument parsing shared by twin-fit and twin-compare: errors on one line naming the flag, number
types that refuse NaN, infinities and out-of-range values, and a checked plot path.

argparse prints its usage block before an error; a user who typed one wrong flag needs one line
that names it (the project's rule for bad input), so ``OneLineParser.error`` prints only that.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

EXIT_USAGE = 2  # argparse's own exit status for a usage error


class OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line error (``prog: error: message``) and the epilog kept as written."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(**kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


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
