"""Plain CSV logs: time, temperature and heater duty."""

from __future__ import annotations

import itertools
from pathlib import Path

from tools.logs.lines import LogError, is_number, iter_csv_rows, time_series
from tools.logs.registry import Reader
from tools.logs.results import PlainLog

# Plain CSV: time, temperature, duty, in this order; a header names them (duty in 0..1, or in
# percent when the column says so), or the first row is data and duty is in 0..1.
TIME_NAMES = {"t", "t_s", "time", "time_s"}
TEMP_NAMES = {"temp", "temp_c", "temperature", "temperature_c"}
DUTY_NAMES = {"duty", "pwm", "power"}
DUTY_PERCENT_NAMES = {"duty_pct", "duty_percent", "pwm_pct", "power_pct"}


def parse_plain_csv(path: str | Path) -> PlainLog:
    """Three columns: time (s), temperature (C), heater duty. A header row names them, e.g.
    t_s,temp_c,duty or t_s,temp_c,duty_pct (percent, converted to 0..1); without a header the
    first row is data and duty must be in 0..1. Read row by row: memory grows by the samples'
    24 bytes, not by the text."""
    rows = iter_csv_rows(path)
    if (top := next(rows, None)) is None:
        raise LogError(path, 1, "no data lines")
    header_no, header = top
    if len(header) != 3:
        raise LogError(path, header_no, f"{len(header)} columns: expected time, temperature, duty")
    percent = False
    first = None
    if all(is_number(cell) for cell in header):
        first = (header_no, header)  # no header: the first row is data
    else:
        names = [cell.lower() for cell in header]
        percent = names[2] in DUTY_PERCENT_NAMES
        if names[0] not in TIME_NAMES or names[1] not in TEMP_NAMES or not (percent or names[2] in DUTY_NAMES):
            raise LogError(path, header_no, f"header {','.join(header)}: expected time, temperature, duty "
                           "columns (e.g. t_s,temp_c,duty or t_s,temp_c,duty_pct)")
    duty_max = 100.0 if percent else 1.0
    duty_name = "duty (percent)" if percent else "duty (0..1; name the column duty_pct for percent)"
    data = itertools.chain([first] if first else [], rows)
    t_s, temp_c, duty = time_series(path, data, ("time", "temperature", duty_name), duty_max)
    return PlainLog(Path(path), t_s, temp_c, duty / duty_max, percent)


READER = Reader("plain CSV (time, temperature, duty)", lambda head: head.first.count(",") == 2, parse_plain_csv)
