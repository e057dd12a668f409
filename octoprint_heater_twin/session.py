"""One tuning at a time, from the printer's autotune (or a pasted capture) to gains applied and read back.

The phases: ``reading`` (M503: the printer's gains before the autotune), ``autotune`` (M303's output is
the capture, its temperatures the live graph, its bias lines the cycles done), ``tuning`` (twin-tune in its
own process), ``answer``, ``checking`` (the quick proof of gains the user edited), ``applying`` (M301/M304,
M500, then M503 read back) and ``applied``. One bar follows the whole run (``progress``): the autotune's
cycles, then twin-tune's own account of its run. Nothing is sent to the printer but on the user's request (start, apply).
The printer's lines arrive on OctoPrint's serial thread, requests on its web threads and the tune's end
on a thread of its own: every method holds one lock, and every change is published to the tab.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from octoprint_heater_twin import check, tuner
from octoprint_heater_twin.console import (
    ERROR_PREFIX, FAILED, FINISHED, HEATERS, MAX_CYCLES, MIN_CYCLES, Gains, autotune_command, gains_in, is_complaint,
    is_cycle_end, is_ok, is_text, last_gains, reading, received, sent)

IDLE, READING, AUTOTUNE, TUNING, ANSWER, CHECKING, APPLYING, APPLIED = (
    "idle", "reading", "autotune", "tuning", "answer", "checking", "applying", "applied")
BUSY = {READING: "reading the printer's gains", AUTOTUNE: "the autotune is running",
        TUNING: "the twin is tuning", CHECKING: "the twin is checking your gains",
        APPLYING: "the gains are being applied"}
# The bar's share of a run from the printer (the rest is twin-tune's): M303 heats up and swings for minutes, a tune
# takes tens of seconds on a PC and minutes on a Raspberry Pi.
AUTOTUNE_SHARE = 0.5
TRACE_POINTS = 4000  # the live graph's readings kept: 2 h of M303's 2 s reports (Marlin gives up after 20 min)
READBACK_TIMEOUT_S = 60.0  # Apply: M301/M304, M500 and M503 take a second on any printer that is idle
CONSOLE_LINES = 400  # the capture's last lines shown in the tab (an autotune at C8 prints about 150)
NEW_GAINS = "new gains"


class Printer(Protocol):
    """What the session needs of OctoPrint's printer."""

    def refusal(self) -> str | None:
        """Why the printer cannot take an autotune or new gains now (not connected, printing), else None."""

    def send(self, commands: list[str]) -> None:
        """Queue ``commands``; the session hears of each as it goes out (``on_sending``)."""


class Session:
    def __init__(self, runs_dir: Path, printer: Printer, publish: Callable[[dict], None]):
        self.runs_dir = runs_dir
        self.printer = printer
        self.publish = publish
        self.lock = threading.RLock()
        self.phase = IDLE
        self.error: str | None = None
        self.heater = "extruder"
        self.run_id: str | None = None
        self.capture: list[str] = []
        self.reply: list[str] = []  # the printer's lines after our M503
        self.reply_open = False  # our M503 has been sent and its lines are being read
        self.m303 = ""
        self.result: str | None = None  # the autotune's end as Marlin says it: FINISHED, or its failure line
        self.current: Gains | None = None  # the printer's gains, the ones to beat
        self.current_from: str | None = None  # where the plugin read them
        self.progress: tuner.Progress | None = None  # twin-tune's account of its run
        self.target_c = 0.0
        self.cycles = 0  # M303's C
        self.trace: list[tuple[float, float]] = []  # the autotune's readings: (temperature C, power %)
        self.cycle_ends_s: list[float] = []  # when each relay cycle ended (its bias line), monotonic
        self.tune_share = 0.0  # where twin-tune's run starts on the bar
        self.checked: dict | None = None  # the quick proof of edited gains (check.summary)
        self.after_check = ANSWER
        self.messages: list[str] = []
        self.answer: dict | None = None
        self.no_plot: str | None = None  # why the answer has no plot
        self.applied: dict | None = None
        self.problems: list[str] = []  # Apply: what the printer objected to (EEPROM, unknown command)
        self.timer: threading.Timer | None = None
        self.runs = 0
        self.sent_gains = ""  # the gains command Apply sent: what M503 must read back

    # -- requests (the tab's buttons); each returns the one-line reason it is refused, else None ---------
    def start(self, heater: str, target_c: float, cycles: int, timeout_s: float) -> str | None:
        """Run M503, then M303 on ``heater``; the capture is tuned when Marlin reports its gains."""
        if heater not in HEATERS:
            return f"heater {heater!r}: choose one of {', '.join(HEATERS)}"
        if not target_c > 0:
            return f"target {target_c:g} C: must be above 0 C"
        if cycles < MIN_CYCLES:
            return f"cycles {cycles}: Marlin's autotune needs at least {MIN_CYCLES}"
        if cycles > MAX_CYCLES:
            return f"cycles {cycles}: Marlin's M303 runs at most {MAX_CYCLES} (it clamps C to {MIN_CYCLES}..{MAX_CYCLES})"
        with self.lock:
            if refused := self._refusal():
                return refused
            self._new_run(heater)
            self.phase, self.target_c, self.cycles, self.tune_share = READING, target_c, cycles, AUTOTUNE_SHARE
            self.m303 = autotune_command(heater, target_c, cycles)
            self._arm(timeout_s, f"The autotune timed out: no result from the printer within {timeout_s / 60:g} min")
            self.printer.send(["M503", self.m303])
            self._publish()
        return None

    def paste(self, text: str, heater: str) -> str | None:
        """Tune a pasted capture (M303's output, with M503's report for the gains to beat if it has one)."""
        lines = text.splitlines()
        if heater not in HEATERS:
            return f"heater {heater!r}: choose one of {', '.join(HEATERS)}"
        if not any(line.strip() for line in lines):
            return "The pasted capture is empty: paste the console text of an M303 run"
        if not is_text(text):
            return "The capture is not text (it holds control bytes, as a binary file does): paste the console " \
                   "text of an M303 run"
        with self.lock:
            if self.phase in BUSY:
                return f"Busy: {BUSY[self.phase]}"
            self._new_run(heater)
            self.capture = lines
            self.current = last_gains(lines, heater)
            self.current_from = "M503 in the paste" if self.current else None
            self._tune()
        return None

    def check(self, edited: Gains) -> str | None:
        """Prove ``edited`` (the answer's gains as the user changed them) on the twin, quickly (tuner.QUICK)."""
        if refused := _bad_gains(edited):
            return refused
        with self.lock:
            if refused := self._no_answer():
                return refused
            self.after_check, self.phase, self.error, self.checked = self.phase, CHECKING, None, None
            self.progress, self.tune_share, self.messages = None, 0.0, []
            self._publish()
            threading.Thread(target=self._check_in_background, args=(self.runs_dir / str(self.run_id), edited),
                             name="heater_twin.check", daemon=True).start()
        return None

    def apply(self, edited: Gains | None = None) -> str | None:
        """Send the answer's commands (M301/M304, M500), or ``edited``'s once the twin has checked them and seen
        no trip, then M503 to read the gains back."""
        with self.lock:
            if refused := self._no_answer():
                return refused
            assert self.answer is not None
            commands = list(self.answer["commands"]) if edited is None else self._edited_commands(edited)
            if isinstance(commands, str):
                return commands
            if refused := self.printer.refusal():
                return refused
            self.phase, self.applied, self.error = APPLYING, None, None
            self.reply, self.reply_open, self.problems, self.sent_gains = [], False, [], commands[0]
            self._arm(READBACK_TIMEOUT_S, f"The printer did not report its gains within {READBACK_TIMEOUT_S:g} s "
                                          "of M503: are they applied? Check with M503 in the terminal")
            self.printer.send(commands + ["M503"])
            self._publish()
        return None

    def _no_answer(self) -> str | None:
        if self.phase in BUSY:
            return f"Busy: {BUSY[self.phase]}"
        if self.phase not in (ANSWER, APPLIED) or not self.answer or self.answer.get("verdict") != NEW_GAINS:
            return "There are no new gains to apply"
        return None

    def _edited_commands(self, edited: Gains) -> list[str] | str:
        """What Apply sends for ``edited``, or why not: gains the twin has not checked, or saw trip."""
        if refused := _bad_gains(edited):
            return refused
        if self.checked is None or Gains(**self.checked["gains"]) != edited:
            return f"{edited.text()}: check the edited gains on the twin first (Check these gains)"
        if self.checked["trips"]:
            return self.checked["line"]
        return [edited.command(self.heater), "M500"]

    # -- the printer's side (OctoPrint's serial thread) -------------------------------------------------
    def on_sending(self, command: str) -> None:
        """One of our commands is about to go to the printer: what comes back from now on is its reply."""
        with self.lock:
            if command == "M503" and self.phase in (READING, APPLYING):
                self.reply, self.reply_open = [], True
            elif command == self.m303 and self.phase == READING:
                self.current = last_gains(self.reply, self.heater)
                self.current_from = "the printer's M503" if self.current else None
                self.reply_open = False
                self.phase = AUTOTUNE
                self.capture = [sent(command)]
                self._publish()

    def on_received(self, line: str) -> None:
        with self.lock:
            if self.phase == AUTOTUNE:
                self._autotune_line(line)
            elif self.phase == APPLYING:
                self._apply_line(line)
            elif self.phase == READING and self.reply_open:
                self.reply.append(line)

    def on_printer_lost(self, reason: str) -> None:
        """The printer disconnected or is in error (a kill, a closed port)."""
        with self.lock:
            if self.phase in (READING, AUTOTUNE):
                self._fail(self.result if self.result and self.result != FINISHED else
                           f"The printer was lost during the autotune: {reason}")
            elif self.phase == APPLYING:
                self._cancel_timer()
                self.phase, self.error = ANSWER, f"The printer was lost while applying the gains: {reason}"
                self._publish()

    def _autotune_line(self, line: str) -> None:
        self.capture.append(received(line))
        text = line.strip()
        sample = reading(text, self.heater)
        if sample is not None and len(self.trace) < TRACE_POINTS:
            self.trace.append(sample)
        if is_cycle_end(text):
            self.cycle_ends_s.append(time.monotonic())
        self.publish({"line": self.capture[-1], "sample": sample, "cycles_done": len(self.cycle_ends_s),
                      "progress": self._progress()})
        if text.startswith(FINISHED):
            self.result = FINISHED
        elif (FAILED in text or text.startswith(ERROR_PREFIX)) and self.result is None:
            self.result = text  # the firmware's own words
        if not is_ok(text):
            return
        self._cancel_timer()
        if self.result == FINISHED:
            self._tune()
        else:
            self._fail(self.result or f"{self.m303} ended without Marlin's result (no '{FINISHED}' line)")

    def _apply_line(self, line: str) -> None:
        text = line.strip()
        if not self.reply_open:
            if is_complaint(text):
                self.problems.append(text)
            return
        self.reply.append(text)
        assert self.answer is not None
        read = last_gains(self.reply, self.heater)
        if not is_ok(text) or read is None:
            return
        self._cancel_timer()
        code, command = HEATERS[self.heater][0], self.sent_gains
        expected = gains_in(command, self.heater)
        holds = expected is not None and expected.holds(read)
        if not holds:
            said = f"The printer reports {code} {read.text()} after Apply, not the gains sent ({command})"
        elif self.problems:
            said = f"The printer holds {code} {read.text()}, but it answered: {self.problems[0]}"
        else:
            said = f"The printer holds the new gains: {code} {read.text()} (M503), stored with M500"
        self.phase = APPLIED
        self.applied = {"holds": holds and not self.problems, "line": said, "read": read._asdict()}
        self._publish()

    # -- the tune (a thread of its own) -----------------------------------------------------------------
    def _tune(self) -> None:
        run_dir = self.runs_dir / str(self.run_id)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / tuner.CAPTURE).write_text("\n".join(self.capture) + "\n")
        self.phase = TUNING
        self._publish()
        thread = threading.Thread(target=self._tune_in_background, args=(run_dir, self.heater, self.current),
                                  name="heater_twin.tune", daemon=True)
        thread.start()

    def _tune_in_background(self, run_dir: Path, heater: str, current: Gains | None) -> None:
        outcome = tuner.run(run_dir, heater, current, self._on_progress, self._on_message)
        with self.lock:
            if outcome.answer is None:
                self._fail(str(outcome.error))
                return
            self.phase, self.answer, self.no_plot, self.progress = ANSWER, outcome.answer, outcome.no_plot, None
            self._publish()

    def _check_in_background(self, run_dir: Path, edited: Gains) -> None:
        outcome = tuner.check(run_dir, self.heater, edited, self._on_progress, self._on_message)
        with self.lock:
            self.phase, self.progress = self.after_check, None
            if outcome.answer is None:
                self.error = str(outcome.error)
            else:
                assert self.answer is not None
                self.checked = check.summary(edited, outcome.answer, self.answer)
            self._publish()

    def _on_progress(self, progress: tuner.Progress) -> None:
        with self.lock:
            self.progress = progress
            self.publish({"progress": self._progress()})

    def _progress(self) -> dict | None:
        """The run's one bar: done in percent, the time left (None: not known yet) and of what, in a user's words."""
        if self.phase == READING:
            return {"percent": 0, "left_s": None, "left_of": None, "words": "Reading your printer's gains (M503)"}
        if self.phase == AUTOTUNE:
            return self._autotune_progress()
        if self.phase not in (TUNING, CHECKING):
            return None
        twin = self.progress or tuner.Progress(0, None, "starting")
        head = "The twin" if self.phase == TUNING else "The twin checks your edited gains"
        return {"percent": round(100 * self.tune_share + (1 - self.tune_share) * twin.percent),
                "left_s": twin.left_s, "left_of": None, "words": f"{head}: {twin.words}"}

    def _autotune_progress(self) -> dict:
        """M303's share of the bar: the heat-up and first swing, then each of its C cycles; the time left from
        the cycles' own pace, once two have ended."""
        done, ends = min(len(self.cycle_ends_s), self.cycles), self.cycle_ends_s
        left_s = None if len(ends) < 2 else round((ends[-1] - ends[0]) / (len(ends) - 1) * (self.cycles - done))
        words = f"Your printer's autotune ({self.m303}): " + (
            f"{done} of {self.cycles} cycles done" if done else f"heating to {self.target_c:g} C, the first swing")
        return {"percent": round(100 * AUTOTUNE_SHARE * (done + self._heated()) / (self.cycles + 1)),
                "left_s": left_s, "left_of": "the autotune", "words": words}

    def _heated(self) -> float:
        """How far the heat-up has come, 0..1 (the first of the autotune's units: then it swings)."""
        if self.cycle_ends_s:
            return 1.0
        if len(self.trace) < 2 or self.target_c <= self.trace[0][0]:
            return 0.0
        start_c = self.trace[0][0]
        return min(1.0, max(0.0, (self.trace[-1][0] - start_c) / (self.target_c - start_c)))

    def _on_message(self, message: str) -> None:
        with self.lock:
            self.messages.append(message)
            self.publish({"message": message})

    # -- state ----------------------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """What the tab shows (GET, and every change published)."""
        with self.lock:
            return {
                "phase": self.phase, "busy": self.phase in BUSY, "doing": BUSY.get(self.phase), "error": self.error,
                "heater": self.heater, "run": self.run_id, "console": self.capture[-CONSOLE_LINES:],
                "current": None if self.current is None else self.current._asdict(), "current_from": self.current_from,
                "progress": self._progress(), "messages": self.messages, "answer": self.answer,
                "applied": self.applied, "checked": self.checked, "trace": self.trace, "target_c": self.target_c,
                "cycles": self.cycles, "cycles_done": len(self.cycle_ends_s),
                "plot": bool(self.answer and self.answer.get("plot")), "no_plot": self.no_plot,
            }

    def plot(self, compact: bool = False) -> Path | None:
        """The answer's plot (twin-tune's full figure, or the ``compact`` one made for the tab), if it has one."""
        with self.lock:
            if not self.answer or not self.answer.get("plot") or self.run_id is None:
                return None
            path = self.runs_dir / self.run_id / (tuner.TAB_PLOT if compact else tuner.PLOT)
            return path if path.exists() else None

    def _refusal(self) -> str | None:
        if self.phase in BUSY:
            return f"Busy: {BUSY[self.phase]}"
        return self.printer.refusal()

    def _new_run(self, heater: str) -> None:
        self.runs += 1
        self.run_id = f"{time.strftime('%Y%m%d-%H%M%S')}-{self.runs}"
        self.heater, self.error, self.result, self.current, self.current_from = heater, None, None, None, None
        self.capture, self.reply, self.reply_open, self.messages = [], [], False, []
        self.progress, self.answer, self.no_plot, self.applied = None, None, None, None
        self.trace, self.cycle_ends_s, self.cycles, self.tune_share, self.checked = [], [], 0, 0.0, None

    def _fail(self, error: str) -> None:
        self._cancel_timer()
        self.phase, self.error, self.progress = IDLE, error, None
        self._publish()

    def _arm(self, timeout_s: float, error: str) -> None:
        """Fail with ``error`` unless the current step ends (``_cancel_timer``) within ``timeout_s``."""
        self._cancel_timer()
        timer = threading.Timer(timeout_s, self._expire, args=(error,))
        timer.daemon = True
        self.timer = timer
        timer.start()

    def _expire(self, error: str) -> None:
        with self.lock:
            if self.timer is None or threading.current_thread() is not self.timer:
                return  # cancelled, or a newer step's timer
            self.timer = None
            if self.phase == APPLYING:
                self.phase, self.error = ANSWER, error
                self._publish()
            elif self.phase in (READING, AUTOTUNE):
                self._fail(error)

    def _cancel_timer(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def _publish(self) -> None:
        self.publish({"state": self.state()})


def _bad_gains(gains: Gains) -> str | None:
    """Why ``gains`` cannot be a PID's (a field that is not a number >= 0), else None."""
    for name, value in zip(("kp", "ki", "kd"), gains):
        if not value >= 0 or value == float("inf"):
            return f"{name} {value:g}: must be a number >= 0"
    return None
