"""Marlin (and Repetier) M303 autotune console text as a host program shows it: relay cycles,
the 2 s status reports of the tuned heater, the final gains. Pasted text may end mid-line."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from firmware_port.marlin.autotune import STR_CLASSIC_PID, STR_NO_OVERSHOOT
from tools.logs.lines import GAIN_RE, LogError, console_text, data_lines, parse_integer, parse_number, read_lines
from tools.logs.registry import Reader
from tools.logs.results import M303Cycle, M303Log, M303Run, M303Status

COMMAND_RE = re.compile(r"^(?:N\d+\s+)?(M30[36]\b[^*;]*)")
BED_COMMAND_RE = re.compile(r"\b[EP]-1\b")  # M303 E-1 tunes the bed
BIAS_RE = re.compile(r"bias:\s*(\S+)\s+d:\s*(\S+)\s+min:\s*(\S+)\s+max:\s*([-+]?[\d.]+)")
KU_RE = re.compile(r"Ku:\s*(\S+)\s+Tu:\s*(\S+)")
DEFINE_RE = re.compile(r"^#define\s+DEFAULT_(bed|chamber)?K([pid])\s+(\S*)")
RULES = (STR_CLASSIC_PID.strip(), STR_NO_OVERSHOOT.strip())
GAIN_LINE_RE = re.compile(r"^K[pid]:")
STATUS_RE = re.compile(r"^[TB]:")  # Marlin's 2 s heater report, " T:210.00 /0.00 B:60.00 /0.00 @:64 B@:0"
TEMP_FIELD_RE = re.compile(r"(?<![\w@])([TB]):\s*([^\s/]+)(?:\s*/\s*([^\s/]+))?")
POWER_FIELD_RE = re.compile(r"(?<![\w@])(B?@):(\S*)")
MARLIN_POWER_MAX = 127  # soft-PWM amount, (bias + d) >> 1
REPETIER_POWER_MAX = 255  # Repetier prints bias + d
REPETIER_HINT = "Repetier-Firmware ('Info:'/'busy:' lines): @ is on 0..255, Ku comes from the full swing"
FIRMWARE_HINTS = (
    (re.compile(r"^(?:Info|busy):"), REPETIER_HINT),
    (re.compile(r"\bP:[-\d.]+ A:[-\d.]+|constants from above"), "Prusa-Firmware (P:/A: fields, 'from above')"),
    (re.compile(STR_NO_OVERSHOOT.strip()), "Marlin 2.x: the bed is tuned by the 'No overshoot' rule"),
    (re.compile(r"PID Autotune failed"), "an autotune failed"),
    (re.compile(r"MPC Autotune"), "Marlin MPC autotune (M306): no relay cycles"),
)
CONSOLE_RE = re.compile(r"^(?:bias:|Ku:|PID Autotune|MPC Autotune|#define\s+DEFAULT_|[TB]:\s*[-\d.])")
UNKNOWN_HEATER = "?"  # a cycle of a run no line of the capture attributes (_M303Reader says which lines do)
INCOMPLETE_STATUS = "status line without the power of each heater it shows (cut or elided)"
HEATER_WORDS = {"T": "hotend", "B": "bed"}
NOT_YET = -1  # a run whose first cycle is not read yet


def _status_sample(path: str | Path, line_no: int, temps: dict[str, tuple[float, float]], text: str,
                   heater: str) -> M303Status | None:
    """The tuned heater's reading in a status line, or None if the line lacks a power field it
    should have (Marlin and Repetier print @: and B@: whenever they show T and B)."""
    powers = dict(POWER_FIELD_RE.findall(text))
    both = "T" in temps and "B" in temps
    if (both and len(powers.keys() & {"@", "B@"}) < 2) or (not both and "@" not in powers):
        return None
    power_key = "B@" if heater == "B" and both else "@"
    return M303Status(line_no, *temps[heater], parse_integer(path, line_no, powers[power_key], f"{power_key} power"),
                      heater)


def _idle_reading(temps: dict[str, tuple[float, float]], text: str, heater: str) -> float | None:
    """The other heater's reading on a status line showing both, if it has no target and no power
    (a bed at rest reads about the room: an ambient for the fit)."""
    other = "B" if heater == "T" else "T"
    powers = dict(POWER_FIELD_RE.findall(text))
    power = powers.get("B@" if other == "B" else "@")
    if other not in temps or power != "0":
        return None
    reading_c, target_c = temps[other]
    return reading_c if math.isnan(target_c) or target_c == 0 else None


def _powered_heater(text: str) -> str | None:
    """On a status line showing both heaters' power, the one heater powered ("T" or "B"), else None.
    M303 switches every other heater off when it starts (PID_autotune calls disable_all_heaters in Marlin's
    temperature.cpp), so during a run the powered one is the tuned one."""
    powers = dict(POWER_FIELD_RE.findall(text))
    if not {"@", "B@"} <= powers.keys() or not all(p.isdigit() for p in (powers["@"], powers["B@"])):
        return None
    on = [key for key, field in (("T", "@"), ("B", "B@")) if int(powers[field]) > 0]
    return on[0] if len(on) == 1 else None


@dataclass
class _M303Reader:
    """What parse_m303 has read so far; ``read`` takes one console line (host prefix removed).

    A capture holds one or more runs, each from an M303 command or "PID Autotune start" on. A run's
    heater is what its first line that says so says: the command (E-1: the bed), a status report of one
    heater (T: or B:), a report of both where one alone is powered, a #define DEFAULT_bedK or DEFAULT_K
    line, or Marlin 2.x's bed rule "No overshoot". Cycles read before it are "?" until then (and stay
    so where no line says); reports of both heaters wait for it (and are read as the hotend's if none
    says)."""

    path: str | Path
    commands: list[tuple[int, str]] = field(default_factory=list)
    cycles: list[M303Cycle] = field(default_factory=list)
    status: list[M303Status] = field(default_factory=list)
    skipped: list[tuple[int, str]] = field(default_factory=list)
    hints: list[str] = field(default_factory=list)
    idle_c: list[float] = field(default_factory=list)
    defines: dict[str, float] = field(default_factory=dict)
    finished: bool = False
    runs: list[M303Run] = field(default_factory=list)
    run_first_cycle: int = NOT_YET  # index in cycles of the current run's first cycle
    run_has_data: bool = False  # the current run has a cycle or a status line
    waiting: list[tuple[int, dict[str, tuple[float, float]], str]] = field(default_factory=list)  # both-heater reports

    def read(self, no: int, text: str) -> None:
        for pattern, hint in FIRMWARE_HINTS:
            if pattern.search(text) and not any(h.startswith(hint) for h in self.hints):
                self.hints.append(f"{hint} (line {no})")
        self.finished = self.finished or "PID Autotune finished" in text
        if not self.runs or ("PID Autotune start" in text and self.run_has_data):
            self._new_run(no)
        if m := COMMAND_RE.match(text):
            self.commands.append((no, m[1].strip()))
            self._new_run(no)
            self._learn("B" if BED_COMMAND_RE.search(m[1]) else "T", f"the {m[1].split()[0]} command (line {no})")
        elif m := DEFINE_RE.match(text):
            self.defines[m[2].lower()] = parse_number(self.path, no, m[3], f"DEFAULT_{m[1] or ''}K{m[2]}")
            if m[1] != "chamber":
                self._learn("B" if m[1] else "T", f"line {no}: #define DEFAULT_{m[1] or ''}K{m[2]}")
        else:
            rest = self._relay_values(no, text)
            if rest in RULES:
                self._cycle(no, "rule").rule = rest
                if rest == STR_NO_OVERSHOOT.strip():
                    self._learn("B", f"line {no}: the '{rest}' rule, Marlin 2.x's for the bed")
            elif GAIN_LINE_RE.match(rest):
                for k, value in GAIN_RE.findall(rest):
                    attr = "k" + k.lower()
                    setattr(self._cycle(no, attr), attr, parse_number(self.path, no, value, "K" + k))
            elif STATUS_RE.match(rest):
                self._status_line(no, rest)

    @property
    def heater(self) -> str:
        """The current run's heater as far as its lines say: "T", "B" or "?"."""
        return self.runs[-1].heater

    def _new_run(self, no: int) -> None:
        """Close the current run (if it holds anything) and start one at line no."""
        self.close_run()
        if self.runs and not self.run_has_data and self.heater == UNKNOWN_HEATER:
            self.runs.pop()  # nothing in it, nothing said about it
        self.runs.append(M303Run(no, UNKNOWN_HEATER, ""))
        self.run_first_cycle, self.run_has_data = NOT_YET, False

    def close_run(self) -> None:
        """Reports of both heaters that no line of the run attributed: read as the hotend's (M303's default E0)."""
        for waiting in self.waiting:
            self._sample(*waiting, "T")
        self.waiting.clear()

    def _learn(self, heater: str, evidence: str) -> None:
        """A line says which heater the current run tunes: the first such line decides; the run's cycles
        so far get it, and the reports of both heaters that waited for it are read."""
        if self.heater != UNKNOWN_HEATER:
            return
        self.runs[-1] = self.runs[-1]._replace(heater=heater, evidence=evidence)
        if self.run_first_cycle != NOT_YET:
            for cycle in self.cycles[self.run_first_cycle:]:
                cycle.heater = heater
        for waiting in self.waiting:
            self._sample(*waiting, heater)
        self.waiting.clear()

    def _add_cycle(self, cycle: M303Cycle) -> M303Cycle:
        if self.run_first_cycle == NOT_YET:
            self.run_first_cycle = len(self.cycles)
        self.run_has_data = True
        self.cycles.append(cycle)
        return cycle

    def _cycle(self, line_no: int, attr: str) -> M303Cycle:
        """The cycle a value belongs to: the last one, or a new one if the last has it already."""
        if not self.cycles or getattr(self.cycles[-1], attr) is not None:
            return self._add_cycle(M303Cycle(line_no, self.heater))
        return self.cycles[-1]

    def _relay_values(self, no: int, text: str) -> str:
        """Read the bias/d/min/max and Ku/Tu at the start of a line; the rest of the line."""
        path, rest = self.path, text
        if "bias:" in rest:
            if not (m := BIAS_RE.search(rest)):
                raise LogError(path, no, "a bias line without bias, d, min and max")
            self._add_cycle(M303Cycle(no, self.heater, parse_integer(path, no, m[1], "bias"),
                                      parse_integer(path, no, m[2], "d"), parse_number(path, no, m[3], "min"),
                                      parse_number(path, no, m[4], "max")))
            rest = rest[m.end() :].strip()
        if "Ku:" in rest:
            if not (m := KU_RE.search(rest)):
                raise LogError(path, no, "a Ku line without Ku and Tu")
            c = self._cycle(no, "ku")
            c.ku, c.tu_s = parse_number(path, no, m[1], "Ku"), parse_number(path, no, m[2], "Tu", 0.0)
            rest = rest[m.end() :].strip()
        return rest

    def _status_line(self, no: int, rest: str) -> None:
        """A heater report: evidence of the run's heater where it shows one heater, or one powered; its sample
        (a report of one heater is that heater's; of both, the run's heater's, once a line says which)."""
        if not TEMP_FIELD_RE.match(rest):
            raise LogError(self.path, no, f"a status line without a temperature after {rest[:2]}")
        temps = {key: (parse_number(self.path, no, temp, f"{key} temperature"),
                       parse_number(self.path, no, target, f"{key} target") if target else math.nan)
                 for key, temp, target in TEMP_FIELD_RE.findall(rest)}
        self.run_has_data = True
        if len(temps) == 1:
            key = next(iter(temps))
            self._learn(key, f"line {no} reports the {HEATER_WORDS[key]} alone ({key}:)")
            self._sample(no, temps, rest, key)
            return
        if (powered := _powered_heater(rest)) is not None:
            self._learn(powered, f"line {no} reports both heaters, the {HEATER_WORDS[powered]} alone powered "
                                 "(M303 switches the others off)")
        if self.heater == UNKNOWN_HEATER:
            self.waiting.append((no, temps, rest))
        else:
            self._sample(no, temps, rest, self.heater)

    def _sample(self, no: int, temps: dict[str, tuple[float, float]], rest: str, heater: str) -> None:
        """A report's reading of ``heater`` (skipped if the line is incomplete), and the other's if idle."""
        if len(temps) > 1 and (reading := _idle_reading(temps, rest, heater)) is not None:
            self.idle_c.append(reading)
        sample = _status_sample(self.path, no, temps, rest, heater)
        if sample is None:
            self.skipped.append((no, INCOMPLETE_STATUS))
        else:
            self.status.append(sample)

    def final_gains(self) -> tuple[float, float, float] | None:
        """The #define lines, else the last cycle's gains if the run finished."""
        last = self.cycles[-1] if self.cycles else None
        if len(self.defines) == 3:
            return (self.defines["p"], self.defines["i"], self.defines["d"])
        if self.finished and last and last.kp is not None and last.ki is not None and last.kd is not None:
            return (last.kp, last.ki, last.kd)
        return None


def results_only(text: str) -> str:
    """An M303 console capture without its status reports: the lines whose console text is a heater
    report (T:/B: ... @:) deleted, everything else kept. What a user posts who copies only the
    result lines."""
    kept = [line for line in text.splitlines(keepends=True) if not STATUS_RE.match(console_text(line))]
    return "".join(kept)


def parse_m303(path: str | Path) -> M303Log:
    """Marlin's M303 output as a host console shows it: bias/d/min/max lines (status text may follow
    on the same line), Ku/Tu (same or next line), the rule, Kp/Ki/Kd (one line or three), the
    #define lines, and the 2 s status reports of the tuned heater (T or B, from M303 E-1 or the
    report's shape). Repetier's output and M306 status traces read the same way."""
    lines = data_lines(path, read_lines(path, cut_last_line_ok=True))  # pasted text: the status reader copes
    reader = _M303Reader(path)
    for no, raw in lines:
        reader.read(no, console_text(raw))
    reader.close_run()
    if not (reader.cycles or reader.status or reader.defines):
        raise LogError(path, lines[-1][0], "no autotune output: no bias, Ku/Tu, gain, #define or status line")
    hints = reader.hints
    power_max = REPETIER_POWER_MAX if any(h.startswith(REPETIER_HINT) for h in hints) else MARLIN_POWER_MAX
    rule = next((c.rule for c in reversed(reader.cycles) if c.rule), None)
    return M303Log(Path(path), reader.commands, reader.cycles, reader.status, reader.final_gains(), rule, power_max,
                   hints, reader.skipped, reader.idle_c, reader.runs)


READER = Reader("M303 console text (Marlin, Repetier)", lambda head: any(CONSOLE_RE.match(text) for text in head.texts), parse_m303)
