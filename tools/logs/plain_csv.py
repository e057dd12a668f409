"""Plain CSV logs: time, temperature and heater duty."""

from __future__ import annotations

from pathlib import Path

from tools.logs.lines import LogError, csv_rows, is_number, time_series
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
    first row is data and duty must be in 0..1."""
    _, rows = csv_rows(path)
    header_no, header = rows[0]
    if len(header) != 3:
        raise LogError(path, header_no, f"{len(header)} columns: expected time, temperature, duty")
    percent = False
    if not all(is_number(cell) for cell in header):
        names = [cell.lower() for cell in header]
        percent = names[2] in DUTY_PERCENT_NAMES
        if names[0] not in TIME_NAMES or names[1] not in TEMP_NAMES or not (percent or names[2] in DUTY_NAMES):
            raise LogError(path, header_no, f"header {','.join(header)}: expected time, temperature, duty "
                           "columns (e.g. t_s,temp_c,duty or t_s,temp_c,duty_pct)")
        rows = rows[1:]
    if not rows:
        raise LogError(path, header_no, "no data rows")
    duty_max = 100.0 if percent else 1.0
    duty_name = "duty (percent)" if percent else "duty (0..1; name the column duty_pct for percent)"
    t_s, temp_c, duty = time_series(path, rows, ("time", "temperature", duty_name), duty_max)
    return PlainLog(Path(path), t_s, temp_c, duty / duty_max, percent)
