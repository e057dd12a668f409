"""Klipper PID_CALIBRATE results: gains as Klipper prints or saves them, with their sources."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from tools.logs.lines import GAIN_RE, LogError, console_text, is_comment, parse_number, read_lines
from tools.logs.registry import Reader
from tools.logs.results import PidCalibrateResult, PidCalibrateResults

PID_HEADING_RE = re.compile(r"^\[(\d+)\]\s+(https?://\S+)?")
KLIPPER_HEATER_RE = re.compile(r"\b(extruder\d*|heater_bed)\b")
MAX_POWER_RE = re.compile(r"\bmax_power ([\d.]+)")
RESULT_RE = re.compile(r"^(?:Autotune: final:|// PID parameters:|pid_K[pid]\s*[=:])", re.IGNORECASE)
INCOMPLETE_GAINS = "Kp, Ki and Kd are not all given in this entry"


@dataclass
class _PidReader:
    """What parse_pid_calibrate_results has read so far: the entry's context, the gains waiting
    for the rest of their set, the complete sets."""

    path: str | Path
    results: list[PidCalibrateResult] = field(default_factory=list)
    entry: str = ""
    label: str | None = None
    log_file: str | None = None
    heater: str | None = None
    gains: dict[str, float] = field(default_factory=dict)
    gains_no: int = 0  # the line of the first gain still waiting for the others

    def read(self, no: int, raw: str) -> None:
        comment = is_comment(raw)
        text = raw[2:].strip() if comment else console_text(raw)
        if comment:
            self._comment_context(text)
        if text.split(" ", 1)[0].endswith(".csv"):
            self.log_file = text.split(" ", 1)[0]
        if m := KLIPPER_HEATER_RE.search(text):
            self.heater = m[1]
        max_power = float(m[1]) if (m := MAX_POWER_RE.search(text)) else 1.0
        if comment and "pid_kp" not in text.lower():
            return  # prose about gains ("Tu = 2*Kp/Ki"); the comment table holds pid_kp = .. values
        for k, value in GAIN_RE.findall(text):
            self._gain(no, k.lower(), value, max_power)

    def _comment_context(self, text: str) -> None:
        """An entry heading starts a new source (no gains may be pending); "<label>:" refines it."""
        if m := PID_HEADING_RE.match(text):
            self.require_no_pending_gains()
            self.entry = " ".join(filter(None, (f"[{m[1]}]", m[2])))
            self.label, self.log_file, self.heater = None, None, None
        elif text.endswith(":"):
            self.label = text[:-1]

    def _gain(self, no: int, k: str, value: str, max_power: float) -> None:
        if k in self.gains:
            raise LogError(self.path, no, f"K{k} again before the set of Kp, Ki, Kd is complete")
        self.gains_no = self.gains_no if self.gains else no
        self.gains[k] = parse_number(self.path, no, value, f"K{k}", 0.0)
        if len(self.gains) == 3:
            source = " ".join(s for s in (self.entry, self.log_file, self.label) if s)
            g = self.gains
            self.results.append(PidCalibrateResult(no, source, self.heater, g["p"], g["i"], g["d"], max_power))
            self.gains = {}

    def require_no_pending_gains(self) -> None:
        if self.gains:
            raise LogError(self.path, self.gains_no, INCOMPLETE_GAINS)


def parse_pid_calibrate_results(path: str | Path) -> PidCalibrateResults:
    """Klipper PID gains in any of the forms the results collection holds: "Autotune: final:
    Kp=.. Ki=.. Kd=..", "PID parameters: pid_Kp=.. pid_Ki=.. pid_Kd=..", "pid_kp = .." (one line
    each or on one line), also in the comment table of SAVE_CONFIG values. An entry heading
    "# [n] <url> ..." names the source; "# <label>:" lines and a "<file>.csv" name refine it, a
    heater name (extruder, heater_bed) or "max_power x" on a line applies to the gains after it."""
    lines = read_lines(path)
    reader = _PidReader(path)
    for no, raw in lines:
        reader.read(no, raw)
    reader.require_no_pending_gains()
    if not reader.results:
        raise LogError(path, lines[-1][0] if lines else 1, "no PID gains")
    return PidCalibrateResults(reader.results)


READER = Reader("Klipper PID_CALIBRATE results", lambda head: any(RESULT_RE.match(text) for text in head.texts),
                parse_pid_calibrate_results)
