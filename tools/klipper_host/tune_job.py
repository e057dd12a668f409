"""twin-tune on a klippy.log for the agent: run as a child process (``--json`` for the answer,
``--progress lines`` for the console), and a one-line summary of its proof.

The child gets SIGTERM if the agent dies (Linux's PR_SET_PDEATHSIG), so no tune runs on unattended,
and runs at nice 10: a minute of full CPU must not starve klippy on the printer's host (klippy loses
its MCU after a few seconds without running; at 10 x real time in the tests, after 0.4 s).
"""

from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from tools.klipper_host.printer import Heater

PR_SET_PDEATHSIG = 1
NICE = 10
PROGRESS = "progress: "
REPORT_FILE = "twin-tune.txt"


class TuneFailed(RuntimeError):
    """twin-tune gave no answer: its own one-line reason (exit status 1-3) or an internal error."""


def _child_setup() -> None:
    """In the child before twin-tune starts: SIGTERM when the agent's job thread dies; a lower priority."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    os.nice(NICE)


def twin_tune_command(log: Path, heater: Heater, target_c: float, loop: str, answer: Path,
                      extra: tuple[str, ...]) -> list[str]:
    assert heater.gains is not None
    gains = "pid_Kp={:.6g} pid_Ki={:.6g} pid_Kd={:.6g}".format(*heater.gains)
    return [sys.executable, "-m", "tools.cli.tune", "--from-log", str(log), "--heater", heater.name,
            "--target", f"{target_c:g}", "--loop", loop, "--current-gains", gains, "--json", str(answer),
            "--plot", "none", "--progress", "lines", *extra]


def run_twin_tune(log: Path, heater: Heater, target_c: float, loop: str, workdir: Path, extra: tuple[str, ...],
                  progress: Callable[[str], None]) -> dict:
    """twin-tune's JSON answer; ``progress`` gets a line as each step of its work starts and ends."""
    answer = workdir / "twin-tune.json"
    answer.unlink(missing_ok=True)
    command = twin_tune_command(log, heater, target_c, loop, answer, extra)
    with open(workdir / REPORT_FILE, "w") as report:
        proc = subprocess.Popen(command, stdout=report, stderr=subprocess.PIPE, text=True,
                                preexec_fn=_child_setup, cwd=Path(__file__).resolve().parents[2])
        assert proc.stderr is not None
        last_step, last_line = "", ""
        for line in proc.stderr:
            line = line.strip()
            if line.startswith(PROGRESS):
                step, _, count = line[len(PROGRESS):].rpartition(" ")
                done, _, total = count.partition("/")
                if step != last_step or done == total:
                    progress(f"TWIN_TUNE: {step} {count}")
                last_step = step
            elif line:
                last_line = line
        status = proc.wait()
    if status != 0 or not answer.exists():
        raise TuneFailed(f"twin-tune exited {status}: {last_line or 'no message'}")
    return json.loads(answer.read_text())


def proof_summary(answer: dict) -> str:
    """The proof's rows in a line: plants and seeds, trips, worst overshoot and hold of the answer and yours."""
    rows = answer.get("proof") or []
    if not rows:
        return "none (the twin could not model the heater: see why)"
    members = sorted({r["member"] for r in rows})
    seeds = rows[0]["runs"]

    def worst(candidate: str, key: str) -> float:
        return max(r[key][1] for r in rows if r["candidate"] == candidate)

    def trips(candidate: str) -> int:
        return sum(r["trips"] for r in rows if r["candidate"] == candidate)

    text = f"{len(members)} plants x {seeds} noise seeds, yours: {trips('yours')} trips, worst overshoot " \
           f"{worst('yours', 'overshoot_c'):.2f} C, worst hold {worst('yours', 'hold_error_c'):.2f} C"
    if any(r["candidate"] == "answer" for r in rows):
        text += f", the answer: {trips('answer')} trips, worst overshoot {worst('answer', 'overshoot_c'):.2f} C, " \
                f"worst hold {worst('answer', 'hold_error_c'):.2f} C"
    return text
