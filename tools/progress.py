"""Progress of a long run's steps (fitting, searching, proving), for a terminal or for a program: tqdm bars
on stderr, hidden when stderr is not a terminal (tqdm's ``disable=None``), or one line per step of work,
``progress: <step> <done>/<total>`` (what the OctoPrint plugin reads)."""

from __future__ import annotations

import sys
from collections.abc import Callable

from tqdm import tqdm
from twin.limits import UserError

PROGRESS_MODES = ("bar", "lines")


class Steps:
    """Progress of a run's steps (fitting, searching, proving): ``steps(what, total)`` gives the step's
    ``advance(n=1)``; a tqdm bar per step, or ``progress: <what> <done>/<total>`` lines on stderr."""

    def __init__(self, mode: str = "bar"):
        if mode not in PROGRESS_MODES:
            raise UserError(f"--progress {mode!r}: choose one of: {', '.join(PROGRESS_MODES)}")
        self.mode = mode

    def __repr__(self) -> str:
        return f"Steps({self.mode!r})"

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
