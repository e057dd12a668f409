"""Klipper heater tests: PID_CALIBRATE WRITE_FILE=1 output, or the project's CSV of it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from tools.logs.lines import (
    LogError,
    data_lines,
    head_lines,
    iter_csv_rows,
    parse_number,
    read_lines,
    require_increasing,
    time_series,
)
from tools.logs.registry import Reader
from tools.logs.results import HeattestLog

HEATTEST_CSV_HEADER = "t_s,temp_c,pwm"  # the project's CSV form of a heattest (pwm in force per sample)
PWM_EVENT_RE = re.compile(r"^pwm: (\S+) (\S+)$")  # pid_calibrate.py WRITE_FILE: "pwm: %.3f %.3f"


def parse_heattest(path: str | Path) -> HeattestLog:
    """A Klipper heater test: PID_CALIBRATE WRITE_FILE=1 output ("pwm: <t> <duty>" events and
    "<t> <temp>" samples; duty before the first event is 0), or the project's CSV of it
    (t_s,temp_c,pwm with the duty in force at each sample)."""
    if head_lines(path, 1)[0][1] == HEATTEST_CSV_HEADER:  # the CSV ends every line: read as CSV, strictly
        rows = iter_csv_rows(path)
        next(rows)
        t_s, temp_c, pwm = time_series(path, rows, ("t_s", "temp_c", "pwm"), 1.0)
        changes = np.flatnonzero(np.diff(pwm, prepend=0.0))
        return HeattestLog(Path(path), t_s, temp_c, pwm, [(float(t_s[i]), float(pwm[i])) for i in changes])
    data = data_lines(path, read_lines(path, cut_last_line_ok=True))  # Klipper writes no newline after the last line
    events, samples = [], []
    for no, text in data:
        if m := PWM_EVENT_RE.match(text):
            events.append((no, parse_number(path, no, m[1], "pwm time"), parse_number(path, no, m[2], "pwm", 0.0, 1.0)))
        elif len(parts := text.split()) == 2:
            samples.append((no, parse_number(path, no, parts[0], "time"),
                            parse_number(path, no, parts[1], "temperature")))
        else:
            raise LogError(path, no, "expected '<time> <temp>' or 'pwm: <time> <duty>'")
    if not samples:
        raise LogError(path, data[-1][0], "no temperature samples")
    for found in (events, samples):
        require_increasing(path, [no for no, _, _ in found], np.array([t for _, t, _ in found]))
    event_t_s = np.array([t for _, t, _ in events])
    event_pwm = np.array([0.0] + [v for _, _, v in events])
    t_s = np.array([t for _, t, _ in samples])
    pwm = event_pwm[np.searchsorted(event_t_s, t_s, side="right")]
    return HeattestLog(Path(path), t_s, np.array([c for _, _, c in samples]), pwm,
                       [(t, v) for _, t, v in events])


READER = Reader("Klipper heattest (open loop)", lambda head: head.first == HEATTEST_CSV_HEADER or head.first.startswith("pwm: "),
                parse_heattest)
