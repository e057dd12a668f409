"""heater-twin's tuner, run as twin-tune in a process of its own (the tune is CPU-heavy: never in
OctoPrint's), at a lower priority so that the server and a print stay responsive.

Its contract (docs/octoprint.md): ``--progress lines`` prints ``progress: <step> <done>/<total>`` on
stderr, anything else there is a message, and on failure the last line is the one-line error. Its exit
status (tools/tuning/defaults.py): 0 a verdict in ``--json``'s file (new gains, or keep your gains, also where
the twin cannot model the heater), 1 no safe answer, 2 a capture it cannot use, 3 neither a model nor the
printer's gains, 70 an internal error (a bug, its traceback in a file the line names).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from octoprint_heater_twin.console import Gains

PROGRESS_RE = re.compile(r"^progress: (.+) (\d+)/(\d+)$")
NICENESS = 10  # below OctoPrint's own priority; a tune takes minutes on a Raspberry Pi
# twin-tune's exit codes (tools/tuning/defaults.py, tools/entry.py: the plugin imports none of the project, which
# runs in its own process; tests/octoprint_plugin/test_tuner_outcome.py checks that these are the same)
EXIT_ANSWER, EXIT_UNSAFE, EXIT_USAGE, EXIT_NO_MODEL, EXIT_INTERNAL = 0, 1, 2, 3, 70
# what the tab says for each status but an answer, before twin-tune's own last line
FAILURES = {EXIT_UNSAFE: "No safe answer: nothing the twin tried beats the firmware's autotune, which trips on some "
                         "plant the capture allows",
            EXIT_USAGE: "The twin cannot use this capture",
            EXIT_NO_MODEL: "No verdict: the twin cannot model this heater and the printer's gains are not known (the "
                           "tab reads them with M503 before the autotune; check that the printer answers M503)",
            EXIT_INTERNAL: "twin-tune hit an internal error (a bug, not your capture): please report it"}
CAPTURE, ANSWER, PLOT, REPORT = "capture.txt", "answer.json", "plot.png", "twin-tune.txt"  # a run's files
NO_MATPLOTLIB = ("No plot: matplotlib is not installed in OctoPrint's environment (install the plugin with its "
                 "octoprint extra, or pip install matplotlib there)")


@dataclass(frozen=True)
class Progress:
    step: str
    done: int
    total: int


@dataclass(frozen=True)
class Outcome:
    """What a tune gave: the answer (ANSWER.json's content), or the one-line error."""

    answer: dict | None
    error: str | None
    no_plot: str | None = None  # why the answer has no plot


def twin_tune() -> Path:
    """The twin-tune console script of OctoPrint's own environment (the ``octoprint`` extra installs both)."""
    return Path(sys.executable).with_name("twin-tune")


def can_plot() -> bool:
    """Whether twin-tune can draw its plot: matplotlib in this environment (the ``octoprint`` extra's)."""
    return importlib.util.find_spec("matplotlib") is not None


def command(run_dir: Path, heater: str, current: Gains | None, plot: bool) -> list[str]:
    args = [str(twin_tune()), "--from-log", str(run_dir / CAPTURE), "--heater", heater]
    if current is not None:
        args += ["--current-gains", current.flag()]
    return args + ["--json", str(run_dir / ANSWER), "--progress", "lines", "--plot", str(run_dir / PLOT) if plot
                   else "none"]


def progress(line: str) -> Progress | None:
    m = PROGRESS_RE.match(line)
    return Progress(m[1], int(m[2]), int(m[3])) if m else None


def _lower_priority() -> None:
    os.nice(NICENESS)


def run(run_dir: Path, heater: str, current: Gains | None, on_progress: Callable[[Progress], None],
        on_message: Callable[[str], None]) -> Outcome:
    """Tune the capture in ``run_dir`` (blocking: call it from a thread); its report goes to REPORT. Without
    matplotlib the answer comes without a plot, and says why."""
    plot = can_plot()
    args = command(run_dir, heater, current, plot)
    last = ""
    try:
        with open(run_dir / REPORT, "w") as report, subprocess.Popen(
                args, stdout=report, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                preexec_fn=_lower_priority) as proc:
            assert proc.stderr is not None
            for raw in proc.stderr:
                line = raw.rstrip()
                if step := progress(line):
                    on_progress(step)
                elif line:
                    last = line
                    on_message(line)
    except OSError as exc:
        return Outcome(None, f"twin-tune could not start: {exc.strerror or exc} ({args[0]})")
    return outcome(proc.returncode, last, run_dir / ANSWER, plot)


def outcome(status: int, last: str, answer_path: Path, plot: bool) -> Outcome:
    """What twin-tune's exit ``status`` (and its ``last`` stderr line) means for the tab."""
    if status == EXIT_ANSWER:
        try:
            return Outcome(json.loads(answer_path.read_text()), None, None if plot else NO_MATPLOTLIB)
        except (OSError, ValueError) as exc:
            return Outcome(None, f"twin-tune's answer {answer_path} is unreadable: {exc}")
    said = FAILURES.get(status, f"twin-tune stopped with status {status}")
    return Outcome(None, f"{said}: {last}" if last else said)
