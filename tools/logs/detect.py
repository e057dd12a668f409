"""load_log: any log this package reads, told apart by its content through the registry of readers
(tools/logs/registry.py). READERS is the registration: the order in which they are asked, the
most specific first (a plain CSV is only three comma-separated columns); a user's readers
(``registry.user_readers``) are asked before them."""

from __future__ import annotations

from pathlib import Path

from tools.logs import heattest, klipper_stats, m303, pid_calibrate, plain_csv, rrf
from tools.logs.lines import LogError
from tools.logs.registry import Head, Reader, user_readers
from tools.logs.results import LOG_TYPES, Log

READERS: tuple[Reader, ...] = (
    klipper_stats.STATS_CSV_READER,
    heattest.READER,
    klipper_stats.KLIPPY_LOG_READER,
    pid_calibrate.READER,
    m303.READER,
    rrf.READER,
    plain_csv.READER,
)


def readers() -> tuple[Reader, ...]:
    """Every reader in the order load_log asks them: the user's, then READERS; ValueError for a name taken twice."""
    every = (*user_readers(), *READERS)
    names = [reader.name for reader in every]
    if taken := sorted({name for name in names if names.count(name) > 1}):
        raise ValueError(f"two log readers name the format {taken[0]!r}: a format's name must be its own")
    return every


def format_names() -> list[str]:
    """The formats load_log reads (RepRapFirmware's heater models are recognised only to be refused)."""
    return [reader.name for reader in readers() if reader is not rrf.READER]


def load_log(path: str | Path) -> Log:
    """Read a log of any format the registry knows, told apart by its head, its format named on it (``log.format``);
    LogError says why a file is none."""
    head = Head.of(path)
    for reader in readers():
        if reader.recognises(head):
            log = reader.read(Path(path))
            if not isinstance(log, LOG_TYPES):
                raise LogError(path, head.lines[0][0], f"the {reader.name} reader returned a {type(log).__name__}, "
                               "not one of tools/logs/results.py's logs")
            log.format = reader.name
            return log
    first_no, first = head.lines[0]
    raise LogError(path, first_no, f"not a log of a known kind ({', '.join(format_names())}): {first[:60]!r}")
