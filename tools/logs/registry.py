"""The registry of log readers: each format's module declares a ``Reader`` (the format's name, how its
text is recognised, its parser), and tools/logs/detect.py lists them in the order ``load_log`` asks.
The reader's name is the log's format: ``load_log`` writes it on the log it returns (``log.format``),
and the CLIs print and choose their checks by it, never by a Python class.

A new format is one module that parses the file into one of the result types (tools/logs/results.py)
and declares its reader, plus one entry in ``detect.READERS``:

    READER = Reader("My firmware's log", lambda head: head.first.startswith("myfw,"), parse_myfw)

A user's reader plugs in without editing the repository, asked before the built-in ones (theirs are
the more specific: a plain CSV is any three columns): an installed package declares it in the entry
point group ``heater_twin.log_readers`` (``myfw = my_package.logs:READER`` in its pyproject's
``[project.entry-points."heater_twin.log_readers"]``), or ``HEATER_TWIN_READERS=my_module:READER``
names it for one run (comma-separated for several; a module on the Python path or in the current
directory). The name must resolve to a ``Reader``: nothing else is called.

A reader recognises a file from its head (``Head``): the first data lines, comment lines left out,
each also without a host program's console prefix. Only the head is read for that, so a long log
is not read twice whole.
"""

from __future__ import annotations

import functools
import os
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

from tools.logs.lines import console_text, head_lines
from tools.logs.results import Log

HEAD_LINES = 2000  # a klippy.log starts with "Start printer at", a console capture with its M303 output
ENTRY_POINT_GROUP = "heater_twin.log_readers"
READERS_ENV = "HEATER_TWIN_READERS"


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


def user_readers() -> tuple[Reader, ...]:
    """The readers ``HEATER_TWIN_READERS`` names, then those of the entry point group; ValueError in one line
    for a name that does not resolve to a Reader."""
    specs = [spec.strip() for spec in os.environ.get(READERS_ENV, "").split(",") if spec.strip()]
    return (*(_resolved(f"{READERS_ENV}={spec}", spec) for spec in specs), *_entry_point_readers())


@functools.cache
def _entry_point_readers() -> tuple[Reader, ...]:
    return tuple(_resolved(f"log reader entry point {ep.name} = {ep.value}", ep.value)
                 for ep in entry_points(group=ENTRY_POINT_GROUP))


def _resolved(where: str, spec: str) -> Reader:
    if str(Path.cwd()) not in sys.path:
        sys.path.append(str(Path.cwd()))
    try:
        found = pkgutil.resolve_name(spec)
    except (ImportError, AttributeError, ValueError, SyntaxError) as exc:  # ValueError: not module:attribute
        raise ValueError(f"{where}: {exc}") from None
    if not isinstance(found, Reader):
        raise ValueError(f"{where}: a {type(found).__name__}, not a tools.logs.registry.Reader")
    return found
