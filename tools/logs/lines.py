"""The line reading every log reader shares: line numbers, comment lines, cut last lines,
numbers checked for range, CSV rows, console text without the host program's prefix, LogError.

Comment lines are ``#`` alone or ``# ...``, the headers added to the captures (Marlin's own
``#define`` lines have no space after the hash and are data).
"""

from __future__ import annotations

import array
import contextvars
import csv
import itertools
import math
import re
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from twin.limits import check_regular_file

# Console text as host programs show it: OctoPrint "Recv: "/"Send: ", Pronterface "READ: "/
# "SENDING:", Printrun ">>> ", Repetier-Host "< 9:12:56 PM: " (and "> ..." for sent lines).
HOST_PREFIX_RE = re.compile(r"^(?:Recv:|Send:|READ:|SENDING:|>>>|[<>] \d{1,2}:\d{2}:\d{2}(?: [AP]M)?:)\s*")
GAIN_RE = re.compile(r"(?<!\w)(?:pid_)?K([pid])\s*[=:]\s*([^\s,]*)", re.IGNORECASE)  # Marlin and Klipper gains


# Who is told how far a reading has got: a CLI's progress bar (``read_progress``), else nobody.
_PROGRESS: contextvars.ContextVar[Callable[[int], None] | None] = contextvars.ContextVar("read_progress", default=None)
PROGRESS_STEP_BYTES = 1 << 20  # reported every megabyte read


@contextmanager
def read_progress(on_bytes: Callable[[int], None]) -> Iterator[None]:
    """Within the block, every reading of a log reports the bytes it has read (a megabyte at a time)
    to on_bytes: how a CLI shows a progress bar for a long log."""
    token = _PROGRESS.set(on_bytes)
    try:
        yield
    finally:
        _PROGRESS.reset(token)


class LogError(ValueError):
    """A log that cannot be read as its format says: ``<file>:<line>: <what is wrong>`` (``<file>: ...``
    for the file as a whole, line_no None)."""

    def __init__(self, path: str | Path, line_no: int | None, what: str):
        super().__init__(f"{path}: {what}" if line_no is None else f"{path}:{line_no}: {what}")
        self.path = path
        self.line_no = line_no


def iter_lines(path: str | Path, cut_last_line_ok: bool = False) -> Iterator[tuple[int, str]]:
    """(line number, text) of each non-blank line, comments included, read one line at a time (a
    long log costs its lines one by one, not all at once).

    A last line without a newline means the file was cut mid-line: LogError, unless the format's
    writer leaves the newline out (cut_last_line_ok).
    """
    report, unreported = _PROGRESS.get(), 0
    try:
        check_regular_file(path)  # a FIFO would block here, a device never end
    except ValueError as exc:
        raise LogError(path, None, str(exc)) from None
    with open(path, "rb") as f:
        for no, raw in enumerate(f, 1):
            unreported += len(raw)
            if report is not None and unreported >= PROGRESS_STEP_BYTES:
                report(unreported)
                unreported = 0
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError:
                raise LogError(path, no, "not UTF-8 text") from None
            if not text.endswith("\n") and not cut_last_line_ok:
                raise LogError(path, no, "the last line has no newline: the file was cut mid-line "
                               "(end it with a newline if the line is complete)")
            text = text.removesuffix("\n")
            if text.strip():
                yield no, text


def read_lines(path: str | Path, cut_last_line_ok: bool = False) -> list[tuple[int, str]]:
    """``iter_lines`` as a list."""
    return list(iter_lines(path, cut_last_line_ok))


def head_lines(path: str | Path, count: int) -> list[tuple[int, str]]:
    """The first ``count`` data lines (comments left out), for telling formats apart without
    reading a long log whole; none at all is an error."""
    lines = iter_lines(path, cut_last_line_ok=True)
    data = list(itertools.islice(((no, text) for no, text in lines if not is_comment(text)), count))
    if not data:
        raise LogError(path, 1, "no data lines")
    return data


def is_comment(text: str) -> bool:
    return text == "#" or text.startswith("# ")


def data_lines(path: str | Path, lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """The non-comment lines; none at all is an error."""
    data = [(no, text) for no, text in lines if not is_comment(text)]
    if not data:
        raise LogError(path, lines[-1][0] if lines else 1, "no data lines")
    return data


def parse_number(path: str | Path, line_no: int, text: str, what: str,
            low: float = -math.inf, high: float = math.inf) -> float:
    """A finite float within [low, high], or LogError naming the line and the field."""
    try:
        value = float(text)
    except ValueError:
        raise LogError(path, line_no, f"{what}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise LogError(path, line_no, f"{what}: {text!r} is not a finite number")
    if not low <= value <= high:
        raise LogError(path, line_no, f"{what} = {text} is outside {low:g}..{high:g}")
    return value


def parse_integer(path: str | Path, line_no: int, text: str, what: str) -> int:
    value = parse_number(path, line_no, text, what)
    if value != int(value):
        raise LogError(path, line_no, f"{what}: {text!r} is not an integer")
    return int(value)


def is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def require_increasing(path: str | Path, line_nos: list[int], t_s: np.ndarray) -> None:
    """Time must increase from sample to sample."""
    bad = np.flatnonzero(np.diff(t_s) <= 0)
    if bad.size:
        i = bad[0] + 1
        raise LogError(path, line_nos[i], f"time {t_s[i]:g} s does not increase (previous sample: {t_s[i - 1]:g} s)")


def iter_csv_rows(path: str | Path, comments: list[str] | None = None) -> Iterator[tuple[int, list[str]]]:
    """A CSV log's rows (header included) with line numbers, one at a time; every row must be as wide
    as the first; the comment texts go to ``comments`` if given."""
    width = None
    for no, text in iter_lines(path):
        if is_comment(text):
            if comments is not None:
                comments.append(text[2:])
            continue
        try:
            fields = next(csv.reader([text], strict=True))
        except csv.Error as e:
            raise LogError(path, no, f"not a CSV line: {e}") from None
        fields = [cell.strip() for cell in fields]
        if width is not None and len(fields) != width:
            raise LogError(path, no, f"{len(fields)} columns where the header has {width}")
        width = len(fields)
        yield no, fields


def csv_rows(path: str | Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """A CSV log's comment texts and its rows (header included) with line numbers (``iter_csv_rows``)."""
    comments: list[str] = []
    rows = list(iter_csv_rows(path, comments))
    if not rows:
        raise LogError(path, 1, "no data lines")
    return comments, rows


def time_series(path: str | Path, rows: Iterable[tuple[int, list[str]]], names: tuple[str, str, str],
                duty_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time, temperature and duty columns (duty within 0..duty_max), read row by row into packed
    arrays (8 bytes a value); time must increase."""
    values = array.array("d")
    t_prev_s, no_prev = -math.inf, 0
    for no, (t_text, temp_text, duty_text) in rows:
        now_s = parse_number(path, no, t_text, names[0])
        if now_s <= t_prev_s:
            raise LogError(path, no, f"time {now_s:g} s does not increase (previous sample: {t_prev_s:g} s)")
        values.extend((now_s, parse_number(path, no, temp_text, names[1]),
                       parse_number(path, no, duty_text, names[2], 0.0, duty_max)))
        t_prev_s, no_prev = now_s, no
    if not values:
        raise LogError(path, no_prev or 1, "no data rows")
    t_s, temp_c, duty = np.frombuffer(values, dtype=float).reshape(-1, 3).T.copy()
    return t_s, temp_c, duty


def console_text(text: str) -> str:
    """A console line without the host program's prefix."""
    return HOST_PREFIX_RE.sub("", text, count=1).strip()
