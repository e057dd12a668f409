"""Argument types shared by the CLIs: numbers that refuse NaN, infinities and out-of-range values, seeds,
and files checked before any work (an output we can write, an input that is a regular text file). The
ranges themselves are twin/limits.py's; the one-line parser is tools/entry.py's ``OneLineParser``."""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable
from pathlib import Path

from tools.cli.numbers import finite_float, ranged_float, ranged_int  # noqa: F401  (re-exported to the CLIs)
from tools.validation.doc_compare import replace_section
from twin.limits import SEED_MAX, UserError, check_regular_file


seed_int = ranged_int(0, SEED_MAX)  # a random seed, as numpy's SeedSequence takes it


def check_output(path: str | Path) -> Path:
    """An output file, checked before any work: not a folder nor a device, in an existing folder where a
    file can be created (not /proc), and writable if it exists; UserError says what is wrong (the caller
    names the file)."""
    path = Path(path)
    if path.is_dir():
        raise UserError("a folder, not a file")
    check_regular_file(path)
    folder = path.absolute().parent
    if not folder.is_dir():
        raise UserError(f"the folder {str(folder)!r} does not exist")
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as exc:
        raise UserError(f"cannot create a file in {str(folder)!r}: {exc.strerror or exc}") from None
    if path.exists():
        try:
            with open(path, "r+b"):
                pass
        except OSError as exc:
            raise UserError(f"cannot write it: {exc.strerror or exc}") from None
    return path


def output_file(text: str) -> Path:
    """An argparse type: ``check_output``'s file."""
    try:
        return check_output(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{text}: {exc}") from None


def read_text_file(path: str | Path) -> str:
    """A regular UTF-8 text file's text; UserError (the reason, for the caller to name the file) for a FIFO,
    a device, binary data or an unreadable file."""
    check_regular_file(path)
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise UserError(str(exc.strerror or exc)) from None


def section_page(path: str | Path, begin: str, end: str) -> str:
    """A page whose generated section a command rewrites (``--doc``), checked before any work: a regular
    UTF-8 file we can write, with the section's markers; its text. UserError says what is wrong."""
    text = read_text_file(path)
    check_output(path)
    if replace_section(text, "", begin, end) is None:
        raise UserError(f"no '{begin} ... -->' / '{end}' markers")
    return text


def doc_page(begin: str, end: str) -> Callable[[str], Path]:
    """An argparse type: a ``section_page`` with these markers (``--doc``)."""

    def parse(text: str) -> Path:
        try:
            section_page(text, begin, end)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"{text}: {exc}") from None
        return Path(text)

    return parse


def plot_path(text: str) -> Path:
    """A plot file we can write (``check_output``) in a format matplotlib can write: checked before any work."""
    path = output_file(text)
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
