"""heater-twin's tuner, run as twin-tune in a process of its own (the tune is CPU-heavy: never in
OctoPrint's), at a lower priority so that the server and a print stay responsive.

Its contract (docs/octoprint.md): ``--progress lines`` prints ``progress: <step> <done>/<total>`` on
stderr, each followed by the whole run's ``run: <percent>% [about <s> s left]: <a user's words>`` (the tab's
one bar, tools/progress.py); anything else there is a message, and on failure the last line is the one-line error. Its exit
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

STEP_RE = re.compile(r"^progress: (.+) (\d+)/(\d+)$")
RUN_RE = re.compile(r"^run: (\d+)%(?: about (\d+) s left)?: (.+)$")
TIMING_RE = re.compile(r"^\(\d+(?:\.\d+)? s\)$")  # twin-tune's "(28.7 s)" after a tune: for a terminal, not the tab
NICENESS = 10  # below OctoPrint's own priority; a tune takes minutes on a Raspberry Pi
# twin-tune's exit codes (tools/tuning/defaults.py, tools/entry.py: the plugin imports none of the project, which
# runs in its own process; tests/octoprint_plugin/test_tuner_outcome.py checks that these are the same)
EXIT_ANSWER, EXIT_UNSAFE, EXIT_USAGE, EXIT_NO_MODEL, EXIT_INTERNAL = 0, 1, 2, 3, 70
EXIT_START = -1  # the plugin's own: twin-tune did not start (no process, so no status of its)
# what the tab says for each status but an answer, before twin-tune's own last line
FAILURES = {EXIT_UNSAFE: "No safe answer: nothing the twin tried beats the firmware's autotune, which trips on some "
                         "plant the capture allows",
            EXIT_USAGE: "The twin cannot use this capture",
            EXIT_NO_MODEL: "No verdict: the twin cannot model this heater and the printer's gains are not known (the "
                           "tab reads them with M503 before the autotune; check that the printer answers M503)",
            EXIT_INTERNAL: "twin-tune hit an internal error (a bug, not your capture): please report it"}
CAPTURE, ANSWER, PLOT, REPORT = "capture.txt", "answer.json", "plot.png", "twin-tune.txt"  # a run's files
TAB_PLOT = "plot-tab.png"  # the answer's compact figure, made for the tab's width (tools/plots/tab_figure.py)
CHECK, CHECK_REPORT = "check.json", "check.txt"  # the quick proof of gains the user edited
# The quick proof: the capture fitted as for the answer (the same plants, the same noise seeds), the edited gains
# as the gains to beat, proven beside Marlin's own rule on the twin's ultimate point: no search, no cross-check.
QUICK = ["--method", "marlin", "--cross-check", "0"]
NO_MATPLOTLIB = ("No plot: matplotlib is not installed in OctoPrint's environment (install the plugin with its "
                 "octoprint extra, or pip install matplotlib there)")


@dataclass(frozen=True)
class Progress:
    """The whole run as twin-tune says it: done in percent, the time left (None: not yet known), in a user's words."""

    percent: int
    left_s: int | None
    words: str


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
    """The tune of the capture in ``run_dir`` against ``current`` (the printer's gains, if known)."""
    args = [str(twin_tune()), "--from-log", str(run_dir / CAPTURE), "--heater", heater]
    if current is not None:
        args += ["--current-gains", current.flag()]
    args += ["--json", str(run_dir / ANSWER), "--progress", "lines"]
    return args + (["--plot", str(run_dir / PLOT), "--plot-compact", str(run_dir / TAB_PLOT)] if plot else
                   ["--plot", "none"])


def check_command(run_dir: Path, heater: str, edited: Gains) -> list[str]:
    """The quick proof of ``edited`` on the plants the capture in ``run_dir`` allows (QUICK)."""
    return [str(twin_tune()), "--from-log", str(run_dir / CAPTURE), "--heater", heater, "--current-gains",
            edited.flag(), *QUICK, "--json", str(run_dir / CHECK), "--progress", "lines", "--plot", "none"]


def progress(line: str) -> Progress | None:
    """The run's line, else None."""
    m = RUN_RE.match(line)
    return Progress(int(m[1]), None if m[2] is None else int(m[2]), m[3]) if m else None


def _lower_priority() -> None:
    os.nice(NICENESS)


def run(run_dir: Path, heater: str, current: Gains | None, on_progress: Callable[[Progress], None],
        on_message: Callable[[str], None]) -> Outcome:
    """Tune the capture in ``run_dir`` (blocking: call it from a thread); its report goes to REPORT. Without
    matplotlib the answer comes without a plot, and says why."""
    plot = can_plot()
    status, last = _twin_tune(command(run_dir, heater, current, plot), run_dir / REPORT, on_progress, on_message)
    return outcome(status, last, run_dir / ANSWER, plot)


def check(run_dir: Path, heater: str, edited: Gains, on_progress: Callable[[Progress], None],
          on_message: Callable[[str], None]) -> Outcome:
    """The quick proof of ``edited`` (blocking); its report goes to CHECK_REPORT, its answer is CHECK's content."""
    status, last = _twin_tune(check_command(run_dir, heater, edited), run_dir / CHECK_REPORT, on_progress,
                              on_message)
    return outcome(status, last, run_dir / CHECK, plot=True)


def _twin_tune(args: list[str], report_path: Path, on_progress: Callable[[Progress], None],
               on_message: Callable[[str], None]) -> tuple[int, str]:
    """Run twin-tune, its report to ``report_path``; (its exit status, its last message)."""
    last = ""
    try:
        with open(report_path, "w") as report, subprocess.Popen(
                args, stdout=report, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
                preexec_fn=_lower_priority) as proc:
            assert proc.stderr is not None
            for raw in proc.stderr:
                line = raw.rstrip()
                if step := progress(line):
                    on_progress(step)
                elif line and not STEP_RE.match(line) and not TIMING_RE.match(line):
                    last = line
                    on_message(line)
    except OSError as exc:
        return EXIT_START, f"twin-tune could not start: {exc.strerror or exc} ({args[0]})"
    return proc.returncode, last


def outcome(status: int, last: str, answer_path: Path, plot: bool) -> Outcome:
    """What twin-tune's exit ``status`` (and its ``last`` stderr line) means for the tab."""
    if status == EXIT_ANSWER:
        try:
            return Outcome(json.loads(answer_path.read_text()), None, None if plot else NO_MATPLOTLIB)
        except (OSError, ValueError) as exc:
            return Outcome(None, f"twin-tune's answer {answer_path} is unreadable: {exc}")
    if status == EXIT_START:
        return Outcome(None, last)
    said = FAILURES.get(status, f"twin-tune stopped with status {status}")
    return Outcome(None, f"{said}: {last}" if last else said)
