"""Progress of a long run's steps (fitting, searching, proving), for a terminal or for a program: tqdm bars
on stderr, hidden when stderr is not a terminal (tqdm's ``disable=None``), or one line per step of work,
``progress: <step> <done>/<total>``, each followed by the whole run's line, ``run: <percent>% [about <s> s
left]: <what a user reads>`` (what the OctoPrint plugin shows: one bar for the run, in a user's words).

The whole run is one fraction: twin-tune's steps come in a known order (STAGES), each a share of a typical
run's time; a step's fraction done moves the run's within its share. The time left is the time so far
scaled by what is left of the fraction, once the fraction says enough (MIN_ESTIMATE_FRACTION).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

from tqdm import tqdm
from twin.limits import UserError

PROGRESS_MODES = ("bar", "lines")
MIN_ESTIMATE_FRACTION = 0.05  # below it the time so far says too little of the time left: none is given


@dataclass(frozen=True)
class Stage:
    """A step of twin-tune's run: the tuner's name for it (a prefix: "searching" is "searching (de)" too), a
    user's words, and its share of a typical run's time."""

    step: str
    words: str
    share: float


# In the order a run takes them (tools/tuning/allowed.py, tools/tuning/tuner.py name the steps). The shares are
# the wall time of each on a warm run of twin-tune on an M303 capture (the tab's case: 3.1 s fitting and
# profiling, 0.6 s replaying, 2.3 s rules, 6.9 s searching, 1.2 s proving and the report, of 14.1 s); a preset
# has no fitting, and its run starts at the rules.
STAGES = (
    Stage("fitting the structures", "Learning your heater from the capture", 0.15),
    Stage("profiling what the log leaves open", "Learning your heater from the capture", 0.07),
    Stage("replaying the log on each plant", "Checking that each heater model replays your autotune", 0.04),
    Stage("the firmware's autotune, the references and the rules", "Trying your gains and the usual tuning rules",
          0.16),
    Stage("searching", "Searching for better gains", 0.48),
    Stage("proving", "Proving the best gains against yours on every heater model", 0.10),
)


def stage_of(step: str) -> int | None:
    """The index in STAGES of the tuner's ``step``, else None (a step the table does not know)."""
    return next((i for i, s in enumerate(STAGES) if step.startswith(s.step)), None)


def words(step: str) -> str:
    """The tuner's ``step`` in a user's words (a step the table does not know as it is named)."""
    index = stage_of(step)
    return step if index is None else STAGES[index].words


class RunProgress:
    """The whole run as one fraction (0..1, never going back) and an estimate of the time left."""

    def __init__(self, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.started_s = clock()
        self.first: int | None = None  # the first stage seen: the run's start (a preset's run has no fitting)
        self.fraction = 0.0

    def __repr__(self) -> str:
        return f"RunProgress({self.estimate()})"

    def update(self, step: str, done: int, total: int) -> None:
        index = stage_of(step)
        if index is None:
            return  # a step the table does not know keeps the run where it is
        if self.first is None:
            self.first = index
        ahead = STAGES[self.first:]
        before = sum(s.share for s in STAGES[self.first:index])
        within = STAGES[index].share * (min(done, total) / total if total > 0 else 1.0)
        self.fraction = max(self.fraction, min(1.0, (before + within) / sum(s.share for s in ahead)))

    def left_s(self) -> float | None:
        """The time left, from the time so far and the fraction done; None while the fraction is too small."""
        if self.fraction < MIN_ESTIMATE_FRACTION:
            return None
        return (self.clock() - self.started_s) * (1.0 - self.fraction) / self.fraction

    def estimate(self) -> str:
        """'62%' or '62%, about 20 s left'."""
        left = self.left_s()
        percent = f"{100 * self.fraction:.0f}%"
        return percent if left is None else f"{percent}, about {left:.0f} s left"

    def line(self, step: str) -> str:
        """The run's line for a program: ``run: 62% about 20 s left: Searching for better gains``."""
        left = self.left_s()
        about = "" if left is None else f" about {left:.0f} s left"
        return f"run: {100 * self.fraction:.0f}%{about}: {words(step)}"


class Steps:
    """Progress of a run's steps (fitting, searching, proving): ``steps(what, total)`` gives the step's
    ``advance(n=1)``; a tqdm bar per step in a user's words with the whole run's share and time left, or
    ``progress: <what> <done>/<total>`` lines on stderr, each followed by the run's line (RunProgress.line)."""

    def __init__(self, mode: str = "bar", clock: Callable[[], float] = time.monotonic):
        if mode not in PROGRESS_MODES:
            raise UserError(f"--progress {mode!r}: choose one of: {', '.join(PROGRESS_MODES)}")
        self.mode = mode
        self.run = RunProgress(clock)

    def __repr__(self) -> str:
        return f"Steps({self.mode!r})"

    def __call__(self, what: str, total: int) -> Callable[..., None]:
        done = [0]
        self.run.update(what, 0, total)
        if self.mode == "lines":
            print(self.run.line(what), file=sys.stderr, flush=True)

            def line(n: int = 1) -> None:
                done[0] += n
                self.run.update(what, done[0], total)
                print(f"progress: {what} {min(done[0], total)}/{total}", file=sys.stderr, flush=True)
                print(self.run.line(what), file=sys.stderr, flush=True)

            return line
        bar = tqdm(total=total, desc=words(what), file=sys.stderr, disable=None, leave=False, dynamic_ncols=True)

        def advance(n: int = 1) -> None:
            done[0] += n
            self.run.update(what, done[0], total)
            bar.set_postfix_str(f"the run {self.run.estimate()}", refresh=False)
            bar.update(n)
            if bar.n >= total:
                bar.close()

        return advance
