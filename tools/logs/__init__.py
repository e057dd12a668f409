"""Readers for captured heater logs, one module per format: Klipper Stats from klippy.log or CSV
(klipper_stats), Klipper heattest (heattest), Marlin/Repetier M303 console text (m303), Klipper
PID_CALIBRATE results (pid_calibrate), plain CSV of time, temperature and duty (plain_csv). The
result types are in results, the shared line reading in lines. Each format's module declares its
``Reader`` (tools/logs/registry.py); ``load_log`` (detect) asks the registered readers in turn, on
the file's first lines only.

The logs stay where they are: every reader takes a path (``hardware_logs_dir()`` finds the shared
captures). All readers share one line reader, which keeps line numbers and skips comment lines:
``#`` alone or ``# ...``, the headers added to the captures (Marlin's own ``#define`` lines have no
space after the hash and are data). A malformed line raises LogError ``<file>:<line>: <what>``: a
wrong column count, a non-number, NaN or infinity, time not increasing, a value out of range. A
last line without a newline was cut mid-line and is an error too, except in Klipper's heattest
files (WRITE_FILE ends without one) and pasted console text. Nothing is interpolated: Klipper
Stats logs come as sessions (one per klippy start), and ``HeaterSeries.segments()`` splits a
session at gaps longer than STATS_GAP_S, where Klipper wrote no lines.
"""

from tools.logs.detect import load_log
from tools.logs.heattest import parse_heattest
from tools.logs.klipper_stats import parse_klipper_stats_csv, parse_klippy_log
from tools.logs.lines import LogError, csv_rows, read_progress
from tools.logs.location import DEFAULT_LOGS, LOGS_ENV, hardware_logs_dir
from tools.logs.m303 import (
    BED_COMMAND_RE,
    MARLIN_POWER_MAX,
    REPETIER_POWER_MAX,
    UNKNOWN_HEATER,
    parse_m303,
    results_only,
)
from tools.logs.pid_calibrate import parse_pid_calibrate_results
from tools.logs.plain_csv import parse_plain_csv
from tools.logs.results import (
    STATS_GAP_S,
    HeaterSeries,
    HeattestLog,
    Log,
    M303Cycle,
    M303Log,
    M303Run,
    M303Status,
    PidCalibrateResult,
    PlainLog,
    StatsLog,
)

__all__ = [
    "BED_COMMAND_RE", "DEFAULT_LOGS", "LOGS_ENV", "MARLIN_POWER_MAX", "REPETIER_POWER_MAX", "STATS_GAP_S",
    "UNKNOWN_HEATER", "HeaterSeries", "HeattestLog", "Log", "LogError", "M303Cycle", "M303Log", "M303Run", "M303Status",
    "PidCalibrateResult", "PlainLog", "StatsLog", "csv_rows", "hardware_logs_dir", "load_log", "parse_heattest",
    "parse_klipper_stats_csv", "parse_klippy_log", "parse_m303", "parse_pid_calibrate_results", "parse_plain_csv",
    "read_progress", "results_only",
]
