"""The registry of log readers: each format's module declares a ``Reader`` (its name, how its text
is recognised, its parser), and tools/logs/detect.py lists them in the order ``load_log`` asks.

A new format is one module that parses the file and declares its reader, plus one entry in
``detect.READERS``:

    READER = Reader("My firmware's log", lambda head: head.first.startswith("myfw,"), parse_myfw)

A reader recognises a file from its head (``Head``): the first data lines, comment lines left out,
each also without a host program's console prefix. Only the head is read for that, so a long log
is not read twice whole.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tools.logs.lines import console_text, head_lines
from tools.logs.results import Log

HEAD_LINES = 2000  # a klippy.log starts with "Start printer at", a console capture with its M303 output


@dataclass(frozen=True)
class Head:
    """The first data lines of a file: (line number, text), and each text without a console prefix."""

    lines: list[tuple[int, str]]
    texts: list[str]

    @property
    def first(self) -> str:
        return self.lines[0][1]

    @classmethod
    def of(cls, path: str | Path) -> Head:
        lines = head_lines(path, HEAD_LINES)
        return cls(lines, [console_text(text) for _, text in lines])


@dataclass(frozen=True)
class Reader:
    """One log format: its name (as error messages list it), a test of a file's head, its parser."""

    name: str
    recognises: Callable[[Head], bool]
    read: Callable[[Path], Log]
