"""Klipper's Stats lines, from klippy.log or from the project's CSV of them, as sessions (one per
klippy start) of heater series. Nothing is interpolated: ``HeaterSeries.segments()`` splits a
session at gaps longer than STATS_GAP_S, where Klipper wrote no lines."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from tools.logs.lines import LogError, csv_rows, is_comment, parse_integer, parse_number, read_lines, require_increasing
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


def _stats_sessions(path: str | Path, rows: list[tuple[int, object, float, dict]]) -> list[dict[str, HeaterSeries]]:
    """Stats rows (line_no, session key, t_s, {heater: (target, temp, pwm)}) as one dict of
    HeaterSeries per run of equal session keys; time must increase within a session."""
    sessions: list[tuple[list[int], list[float], dict[str, list]]] = []
    key = None
    for line_no, row_key, t_s, heaters in rows:
        if not sessions or row_key != key:
            sessions.append(([], [], {}))
            key = row_key
        line_nos, times, samples = sessions[-1]
        line_nos.append(line_no)
        times.append(t_s)
        for name, values in heaters.items():
            samples.setdefault(name, []).append((t_s, *values))
    if not sessions:
        raise LogError(path, 1, "no Stats line reports a heater")
    for line_nos, times, _ in sessions:
        require_increasing(path, line_nos, np.array(times))
    return [{name: HeaterSeries(name, *np.array(values).T) for name, values in samples.items()}
            for _, _, samples in sessions]


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
    comments, rows = csv_rows(path)
    (header_no, header), data = rows[0], rows[1:]
    heaters = [name.removesuffix("_target") for name in header[3::3]]
    expected = ["session", "t_host_s", "print_time_s"] + [f"{h}_{k}" for h in heaters for k in HEATER_KEYS]
    if header != expected:
        raise LogError(path, header_no, "the header is not session,t_host_s,print_time_s followed by "
                       "<heater>_target,<heater>_temp,<heater>_pwm per heater")
    stats_rows = []
    for no, fields in data:
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
            stats_rows.append((no, session, t_s, values))
    config_start = next((i for i, c in enumerate(comments) if c.startswith("----") and "configuration" in c),
                        len(comments))
    config_lines = []
    for comment in comments[config_start + 1 :]:
        if comment.strip().startswith("----"):
            break
        config_lines.append(comment.strip())
    meta = {"klipper_version": _klipper_version(comments), "config": _config_sections(config_lines),
            "comments": comments}
    return StatsLog(Path(path), _stats_sessions(path, stats_rows), meta)


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


def parse_klippy_log(path: str | Path) -> StatsLog:
    """klippy.log's "Stats <t>:" lines (optionally "INFO:root:Stats"), e.g. from Klipper or from
    RunResult.to_klipper_stats(). A new session starts at each "Start printer at" line and
    where the host time does not increase (a reboot resets it). Other lines are ignored."""
    lines = read_lines(path)
    rows = []
    session = 0
    t_prev_s = -math.inf
    in_config = False
    config_lines: list[str] = []
    for no, text in lines:
        if is_comment(text):
            continue
        if in_config:
            if text.startswith("====="):
                in_config = False
            else:
                config_lines.append(text)
        elif text == CONFIG_START and not config_lines:
            in_config = True
        elif START_RE.match(text):
            session += 1
            t_prev_s = -math.inf
        elif m := STATS_LINE_RE.match(text):
            t_s = parse_number(path, no, m[1], "Stats time")
            if t_s <= t_prev_s:
                session += 1
            t_prev_s = t_s
            heaters = _stats_heaters(path, no, m[2])
            if heaters:
                rows.append((no, session, t_s, heaters))
    texts = [text for _, text in lines]
    meta = {"klipper_version": _klipper_version(texts), "config": _config_sections(config_lines), "comments": []}
    return StatsLog(Path(path), _stats_sessions(path, rows), meta)


STATS_CSV_READER = Reader("Klipper Stats CSV", lambda head: head.first.startswith(STATS_CSV_START),
                          parse_klipper_stats_csv)
KLIPPY_LOG_READER = Reader("klippy.log", lambda head: any(KLIPPY_RE.match(text) for text in head.texts),
                           parse_klippy_log)
