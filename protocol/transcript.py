"""The ``--log`` transcript: both directions of the wire with virtual and wall times.

A ``#`` header line, then one line per chunk on the wire::

    <dir> <virtual_s> <wall_s> <data>

``dir`` is ``>`` host to printer, ``<`` printer to host, ``*`` an event ("host connected",
"board reset", "host left"). ``virtual_s`` is the printer's clock (scenario seconds) when the
chunk passed, ``wall_s`` the seconds since the transcript was opened. ``data`` is a Python
literal: the bytes' repr, or the event's text as a str repr; ``line.split(" ", 3)`` and
``ast.literal_eval`` read a line back.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path


class Transcript:
    """The ``--log`` file: both directions of the wire with virtual and wall times (see above)."""

    def __init__(self, path: str | Path, clock: Callable[[], float] = time.monotonic):
        self._file = open(path, "w", encoding="utf-8", buffering=1)  # a line at a time: tail -f works
        self._clock = clock
        self._wall0_s = clock()
        started = datetime.now().astimezone().isoformat(timespec="seconds")
        self._file.write(f"# heater-twin transcript started {started}: dir virtual_s wall_s data "
                         "(> host to printer, < printer to host, * event)\n")

    def __repr__(self) -> str:
        return f"Transcript({self._file.name})"

    def record(self, direction: str, virtual_s: float, data: bytes | str) -> None:
        self._file.write(f"{direction} {virtual_s:.6f} {self._clock() - self._wall0_s:.6f} {data!r}\n")

    def close(self) -> None:
        self._file.close()
