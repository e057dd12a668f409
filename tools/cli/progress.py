"""Progress for the CLIs: tqdm bars on stderr, hidden when stderr is not a terminal (tqdm's
``disable=None``), so a pipe or a test sees only the results; or, for a program reading stderr (the
OctoPrint plugin), one line per step of work, ``progress: <step> <done>/<total>``; and load_log with a
bar over the bytes read."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
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


PROGRESS_MODES = ("bar", "lines")


class Steps:
    """Progress of a run's steps (fitting, searching, proving): ``steps(what, total)`` gives the step's
    ``advance(n=1)``; a tqdm bar per step, or ``progress: <what> <done>/<total>`` lines on stderr."""

    def __init__(self, mode: str = "bar"):
        if mode not in PROGRESS_MODES:
            raise ValueError(f"--progress {mode!r}: choose one of: {', '.join(PROGRESS_MODES)}")
        self.mode = mode

    def __call__(self, what: str, total: int) -> Callable[..., None]:
        if self.mode == "lines":
            done = [0]

            def line(n: int = 1) -> None:
                done[0] += n
                print(f"progress: {what} {min(done[0], total)}/{total}", file=sys.stderr, flush=True)

            return line
        bar = tqdm(total=total, desc=what, file=sys.stderr, disable=None, leave=False, dynamic_ncols=True)

        def advance(n: int = 1) -> None:
            bar.update(n)
            if bar.n >= total:
                bar.close()

        return advance
