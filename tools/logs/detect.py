"""load_log: any log this package reads, told apart by its content through the registry of readers
(tools/logs/registry.py). READERS is the registration: the order in which they are asked, the
most specific first (a plain CSV is only three comma-separated columns)."""

from __future__ import annotations

from pathlib import Path

from tools.logs import heattest, klipper_stats, m303, pid_calibrate, plain_csv, rrf
from tools.logs.lines import LogError
from tools.logs.registry import Head, Reader
from tools.logs.results import Log

READERS: tuple[Reader, ...] = (
    klipper_stats.STATS_CSV_READER,
    heattest.READER,
    klipper_stats.KLIPPY_LOG_READER,
    pid_calibrate.READER,
    m303.READER,
    rrf.READER,
    plain_csv.READER,
)


def load_log(path: str | Path) -> Log:
    """Read a log of any kind the registry knows, told apart by its head; LogError says why a file is none."""
    head = Head.of(path)
    for reader in READERS:
        if reader.recognises(head):
            return reader.read(Path(path))
    first_no, first = head.lines[0]
    kinds = ", ".join(r.name for r in READERS if r.name != rrf.READER.name)
    raise LogError(path, first_no, f"not a log of a known kind ({kinds}): {first[:60]!r}")
