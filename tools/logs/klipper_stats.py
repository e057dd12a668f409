"""Klipper's Stats lines, from klippy.log or from the project's CSV of them, as sessions (one per
klippy start) of heater series. Nothing is interpolated: ``HeaterSeries.segments()`` splits a
session at gaps longer than STATS_GAP_S, where Klipper wrote no lines."""

from __future__ import annotations

import array
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tools.logs.lines import LogError, is_comment, iter_csv_rows, iter_lines, parse_integer, parse_number
from tools.logs.registry import Reader
from tools.logs.results import HeaterSeries, StatsLog

HEATER_KEYS = ("target", "temp", "pwm")  # heaters.py stats(): "<name>: target=%.0f temp=%.1f pwm=%.3f"
STATS_LINE_RE = re.compile(r"^(?:INFO:root:)?Stats ([^\s:]+):(.*)$")  # graphstats.py accepts both
START_RE = re.compile(r"^(?:INFO:root:)?Start printer at ")  # klippy.py, once per (re)start
KLIPPY_RE = re.compile(r"^(?:INFO:root:)?(?:Stats [^\s:]+:|Start printer at )")  # a klippy.log
STATS_CSV_START = "session,t_host_s,"  # the project's CSV of Stats lines
CONFIG_START = "===== Config file ====="  # klippy.log's dump of printer.cfg, up to a "=====" line
VERSION_RE = re.compile(r"Git version: '([^']*)'")
SECTION_RE = re.compile(r"^\[([^\]]+)\]$")
OPTION_RE = re.compile(r"^(\w+)\s*[=:]\s*(.*?)\s*(?:\s[#;].*)?$")


class _Sessions:
    """Stats rows gathered into sessions as they are read: per session and heater, packed columns of
    (t_s, target, temp, pwm), 32 bytes a sample; time must increase within a session."""

    def __init__(self, path: str | Path):
        self.path = path
        self.columns: list[dict[str, array.array]] = []
        self.key: object = None
        self.t_prev_s = -math.inf

    def add(self, line_no: int, key: object, t_s: float, heaters: dict[str, tuple[float, float, float]]) -> None:
        """One Stats row: a session key (a new one, or the first row, starts a session), its time, its heaters."""
        if not self.columns or key != self.key:
            self.columns.append({})
            self.key, self.t_prev_s = key, -math.inf
        if t_s <= self.t_prev_s:
            raise LogError(self.path, line_no, f"time {t_s:g} s does not increase (previous sample: "
                           f"{self.t_prev_s:g} s)")
        self.t_prev_s = t_s
        for name, values in heaters.items():
            self.columns[-1].setdefault(name, array.array("d")).extend((t_s, *values))

    def sessions(self) -> list[dict[str, HeaterSeries]]:
        if not self.columns:
            raise LogError(self.path, 1, "no Stats line reports a heater")
        return [{name: HeaterSeries(name, *np.frombuffer(values, dtype=float).reshape(-1, 4).T.copy())
                 for name, values in session.items()} for session in self.columns]


def _config_sections(lines: list[str]) -> dict[str, dict[str, str]]:
    """Klipper config text as {section: {option: value}}; later values win, as SAVE_CONFIG's
    "#*#" block overrides the file above it. Indented continuation lines are left out."""
    config: dict[str, dict[str, str]] = {}
    section = None
    for line in lines:
        line = line.removeprefix("#*# ")
        if m := SECTION_RE.match(line.strip()):
            section = config.setdefault(m[1], {})
        elif section is not None and (m := OPTION_RE.match(line)):
            section[m[1]] = m[2]
    return config


def _klipper_version(lines: list[str]) -> str | None:
    return next((m[1] for line in lines if (m := VERSION_RE.search(line))), None)


def parse_klipper_stats_csv(path: str | Path) -> StatsLog:
    """The project's CSV of Stats lines: session, t_host_s, print_time_s, then <heater>_target,
    <heater>_temp, <heater>_pwm per heater. A heater's three cells are all given or all empty
    (not in that Stats line); print_time_s is checked but not kept (t_host_s is the time base)."""
    comments: list[str] = []
    rows = iter_csv_rows(path, comments)
    if (top := next(rows, None)) is None:
        raise LogError(path, 1, "no data lines")
    header_no, header = top
    heaters = [name.removesuffix("_target") for name in header[3::3]]
    expected = ["session", "t_host_s", "print_time_s"] + [f"{h}_{k}" for h in heaters for k in HEATER_KEYS]
    if header != expected:
        raise LogError(path, header_no, "the header is not session,t_host_s,print_time_s followed by "
                       "<heater>_target,<heater>_temp,<heater>_pwm per heater")
    sessions = _Sessions(path)
    for no, fields in rows:
        session = parse_integer(path, no, fields[0], "session")
        t_s = parse_number(path, no, fields[1], "t_host_s")
        if fields[2]:
            parse_number(path, no, fields[2], "print_time_s")
        values = {}
        for i, name in enumerate(heaters):
            cells = fields[3 + 3 * i : 6 + 3 * i]
            if any(cells):
                values[name] = _heater_values(path, no, name, dict(zip(HEATER_KEYS, cells)))
        if values:
            sessions.add(no, session, t_s, values)
    config_start = next((i for i, c in enumerate(comments) if c.startswith("----") and "configuration" in c),
                        len(comments))
    config_lines = []
    for comment in comments[config_start + 1 :]:
        if comment.strip().startswith("----"):
            break
        config_lines.append(comment.strip())
    meta = {"klipper_version": _klipper_version(comments), "config": _config_sections(config_lines),
            "comments": comments}
    return StatsLog(Path(path), sessions.sessions(), meta)


def _heater_values(path: str | Path, line_no: int, name: str, cells: dict[str, str]) -> tuple[float, float, float]:
    """A heater's (target, temp, pwm) from its text fields; each must be present."""
    missing = [k for k in HEATER_KEYS if not cells.get(k)]
    if missing:
        raise LogError(path, line_no, f"heater {name}: no {', '.join(missing)}")
    return (parse_number(path, line_no, cells["target"], f"{name} target"),
            parse_number(path, line_no, cells["temp"], f"{name} temp"),
            parse_number(path, line_no, cells["pwm"], f"{name} pwm", 0.0, 1.0))


def _stats_heaters(path: str | Path, line_no: int, body: str) -> dict[str, tuple[float, float, float]]:
    """The heaters in a Stats line, read as graphstats.py does: a token without '=' names the
    fragment ("extruder:") whose target=/temp=/pwm= follow. A fragment without pwm= is a sensor."""
    fragments: dict[str, dict[str, str]] = {}
    prefix = ""
    for token in body.split():
        key, sep, value = token.partition("=")
        if not sep:
            prefix = token.rstrip(":")
        elif key in HEATER_KEYS and prefix:
            fragments.setdefault(prefix, {})[key] = value
    return {name: _heater_values(path, line_no, name, cells) for name, cells in fragments.items() if "pwm" in cells}


@dataclass
class _KlippyReader:
    """What parse_klippy_log has read so far, one line at a time."""

    sessions: _Sessions
    session: int = 0
    t_prev_s: float = -math.inf
    in_config: bool = False
    config_lines: list[str] = field(default_factory=list)
    version: str | None = None

    def read(self, no: int, text: str) -> None:
        if self.version is None and (m := VERSION_RE.search(text)):
            self.version = m[1]
        if self.in_config:
            self.in_config = not text.startswith("=====")
            if self.in_config:
                self.config_lines.append(text)
        elif text == CONFIG_START and not self.config_lines:
            self.in_config = True
        elif START_RE.match(text):
            self.session += 1
            self.t_prev_s = -math.inf
        elif m := STATS_LINE_RE.match(text):
            path = self.sessions.path
            t_s = parse_number(path, no, m[1], "Stats time")
            if t_s <= self.t_prev_s:  # a reboot resets the host time
                self.session += 1
            self.t_prev_s = t_s
            if heaters := _stats_heaters(path, no, m[2]):
                self.sessions.add(no, self.session, t_s, heaters)


def parse_klippy_log(path: str | Path) -> StatsLog:
    """klippy.log's "Stats <t>:" lines (optionally "INFO:root:Stats"), e.g. from Klipper or from
    RunResult.to_klipper_stats(), read one line at a time. A new session starts at each "Start
    printer at" line and where the host time does not increase (a reboot resets it). Other lines
    are ignored."""
    reader = _KlippyReader(_Sessions(path))
    for no, text in iter_lines(path):
        if not is_comment(text):
            reader.read(no, text)
    meta: dict[str, object] = {"klipper_version": reader.version, "config": _config_sections(reader.config_lines),
                               "comments": []}
    return StatsLog(Path(path), reader.sessions.sessions(), meta)


STATS_CSV_READER = Reader("Klipper Stats CSV", lambda head: head.first.startswith(STATS_CSV_START),
                          parse_klipper_stats_csv)
KLIPPY_LOG_READER = Reader("klippy.log", lambda head: any(KLIPPY_RE.match(text) for text in head.texts),
                           parse_klippy_log)
