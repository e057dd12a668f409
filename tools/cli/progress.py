"""Progress bars for the CLIs: tqdm on stderr, hidden when stderr is not a terminal (tqdm's
``disable=None``), so a pipe or a test sees only the results; and load_log with one over the bytes read.
A long run's steps report through tools/progress.py ``Steps``."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from tqdm import tqdm

from tools.logs import Log, load_log, read_progress


@contextmanager
def progress_bar(description: str, total: float | None = None, unit: str = "it") -> Iterator[tqdm]:
    """A tqdm bar for the length of a with block; ``bar.update(n)`` moves it."""
    bar = tqdm(total=total, desc=description, unit=unit, file=sys.stderr, disable=None, leave=False,
               dynamic_ncols=True)
    try:
        yield bar
    finally:
        bar.close()


def load_with_progress(path: str | Path) -> Log:
    """load_log with a bar over the file's bytes (a long log takes a while to read)."""
    with progress_bar("reading", Path(path).stat().st_size, "B") as bar, read_progress(bar.update):
        return load_log(path)
