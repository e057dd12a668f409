"""load_log: any log this package reads, told apart by its content."""

from __future__ import annotations

import re
from pathlib import Path

from tools.logs.heattest import HEATTEST_CSV_HEADER, parse_heattest
from tools.logs.klipper_stats import parse_klipper_stats_csv, parse_klippy_log
from tools.logs.lines import LogError, console_text, data_lines, read_lines
from tools.logs.m303 import parse_m303
from tools.logs.pid_calibrate import parse_pid_calibrate_results
from tools.logs.plain_csv import parse_plain_csv
from tools.logs.results import Log

KLIPPY_RE = re.compile(r"^(?:INFO:root:)?(?:Stats [^\s:]+:|Start printer at )")
PID_RESULT_RE = re.compile(r"^(?:Autotune: final:|// PID parameters:|pid_K[pid]\s*[=:])", re.IGNORECASE)
CONSOLE_RE = re.compile(r"^(?:bias:|Ku:|PID Autotune|MPC Autotune|#define\s+DEFAULT_|[TB]:\s*[-\d.])")
RRF_RE = re.compile(r"^; Heater \d+ model:")


def load_log(path: str | Path) -> Log:
    """Read a log of any kind above, told apart by its content; LogError says why a file is none."""
    data = data_lines(path, read_lines(path, cut_last_line_ok=True))
    first_no, first = data[0]
    if first.startswith("session,t_host_s,"):
        return parse_klipper_stats_csv(path)
    if first == HEATTEST_CSV_HEADER or first.startswith("pwm: "):
        return parse_heattest(path)
    texts = [console_text(text) for _, text in data]
    if any(KLIPPY_RE.match(text) for text in texts):
        return parse_klippy_log(path)
    if any(PID_RESULT_RE.match(text) for text in texts):
        return parse_pid_calibrate_results(path)
    if any(CONSOLE_RE.match(text) for text in texts):
        return parse_m303(path)
    if rrf := next((no for no, text in data if RRF_RE.match(text)), None):
        raise LogError(path, rrf, "RepRapFirmware heater model results ('; Heater n model: ...'): no reader here")
    if first.count(",") == 2:
        return parse_plain_csv(path)
    raise LogError(path, first_no, f"not a log of a known kind (Klipper Stats CSV or klippy.log, heattest, "
                   f"M303 console text, PID_CALIBRATE results, plain CSV): {first[:60]!r}")
