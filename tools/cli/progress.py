"""Progress bars for the CLIs: tqdm on stderr, hidden when stderr is not a terminal (tqdm's
``disable=None``), so a pipe or a test sees only the results."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from tqdm import tqdm


@contextmanager
def progress_bar(description: str, total: float | None = None, unit: str = "it") -> Iterator[tqdm]:
    """A tqdm bar for the length of a with block; ``bar.update(n)`` moves it."""
    bar = tqdm(total=total, desc=description, unit=unit, file=sys.stderr, disable=None, leave=False,
               dynamic_ncols=True)
    try:
        yield bar
    finally:
        bar.close()
