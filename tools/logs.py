"""Readers for captured heater logs: Klipper Stats, Klipper heattest, Marlin M303 console text,
Klipper PID_CALIBRATE results, and plain CSV (time, temperature, duty).

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

from __future__ import annotations

import csv
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from firmware_port.marlin.autotune import STR_CLASSIC_PID, STR_NO_OVERSHOOT

LOGS_ENV = "HEATER_TWIN_HARDWARE_LOGS"
DEFAULT_LOGS = Path(__file__).resolve().parents[2] / "shared" / "hardware_logs"

# Klipper (klippy/extras/statistics.py) writes a Stats line every 1 s of host time while a heater
# is active or a print runs. More than 5 s without one is a gap: heaters idle and cold, klippy
# busy or restarting; the heater's state in between is unknown.
STATS_GAP_S = 5.0
HEATER_KEYS = ("target", "temp", "pwm")  # heaters.py stats(): "<name>: target=%.0f temp=%.1f pwm=%.3f"
STATS_LINE_RE = re.compile(r"^(?:INFO:root:)?Stats ([^\s:]+):(.*)$")  # graphstats.py accepts both
START_RE = re.compile(r"^(?:INFO:root:)?Start printer at ")  # klippy.py, once per (re)start
CONFIG_START = "===== Config file ====="  # klippy.log's dump of printer.cfg, up to a "=====" line
VERSION_RE = re.compile(r"Git version: '([^']*)'")
SECTION_RE = re.compile(r"^\[([^\]]+)\]$")
OPTION_RE = re.compile(r"^(\w+)\s*[=:]\s*(.*?)\s*(?:\s[#;].*)?$")

HEATTEST_CSV_HEADER = "t_s,temp_c,pwm"  # the project's CSV form of a heattest (pwm in force per sample)
PWM_EVENT_RE = re.compile(r"^pwm: (\S+) (\S+)$")  # pid_calibrate.py WRITE_FILE: "pwm: %.3f %.3f"

# Plain CSV: time, temperature, duty, in this order; a header names them (duty in 0..1, or in
# percent when the column says so), or the first row is data and duty is in 0..1.
TIME_NAMES = {"t", "t_s", "time", "time_s"}
TEMP_NAMES = {"temp", "temp_c", "temperature", "temperature_c"}
DUTY_NAMES = {"duty", "pwm", "power"}
DUTY_PERCENT_NAMES = {"duty_pct", "duty_percent", "pwm_pct", "power_pct"}

# Console text as host programs show it: OctoPrint "Recv: "/"Send: ", Pronterface "READ: "/
# "SENDING:", Printrun ">>> ", Repetier-Host "< 9:12:56 PM: " (and "> ..." for sent lines).
HOST_PREFIX_RE = re.compile(r"^(?:Recv:|Send:|READ:|SENDING:|>>>|[<>] \d{1,2}:\d{2}:\d{2}(?: [AP]M)?:)\s*")
COMMAND_RE = re.compile(r"^(?:N\d+\s+)?(M30[36]\b[^*;]*)")
BED_COMMAND_RE = re.compile(r"\b[EP]-1\b")  # M303 E-1 tunes the bed
BIAS_RE = re.compile(r"bias:\s*(\S+)\s+d:\s*(\S+)\s+min:\s*(\S+)\s+max:\s*([-+]?[\d.]+)")
KU_RE = re.compile(r"Ku:\s*(\S+)\s+Tu:\s*(\S+)")
GAIN_RE = re.compile(r"(?<!\w)(?:pid_)?K([pid])\s*[=:]\s*([^\s,]*)", re.IGNORECASE)  # Marlin and Klipper
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
INCOMPLETE_STATUS = "status line without the power of each heater it shows (cut or elided)"

# Klipper PID_CALIBRATE (pid_calibrate.py): Kp = 0.6 Ku 255, Ti = Tu / 2, Td = Tu / 8, and
# Ku = 4 max_power / (pi a) for a relay swing of peak-to-peak 2a.
KLIPPER_PID_PARAM_BASE = 255.0
PID_HEADING_RE = re.compile(r"^\[(\d+)\]\s+(https?://\S+)?")
KLIPPER_HEATER_RE = re.compile(r"\b(extruder\d*|heater_bed)\b")
MAX_POWER_RE = re.compile(r"\bmax_power ([\d.]+)")
INCOMPLETE_GAINS = "Kp, Ki and Kd are not all given in this entry"

KLIPPY_RE = re.compile(r"^(?:INFO:root:)?(?:Stats [^\s:]+:|Start printer at )")
PID_RESULT_RE = re.compile(r"^(?:Autotune: final:|// PID parameters:|pid_K[pid]\s*[=:])", re.IGNORECASE)
CONSOLE_RE = re.compile(r"^(?:bias:|Ku:|PID Autotune|MPC Autotune|#define\s+DEFAULT_|[TB]:\s*[-\d.])")
RRF_RE = re.compile(r"^; Heater \d+ model:")


class LogError(ValueError):
    """A log that cannot be read as its format says: ``<file>:<line>: <what is wrong>``."""

    def __init__(self, path: str | Path, line_no: int, what: str):
        super().__init__(f"{path}:{line_no}: {what}")
        self.path = path
        self.line_no = line_no


def hardware_logs_dir() -> Path:
    """The captured hardware logs: $HEATER_TWIN_HARDWARE_LOGS, else <repo>/../shared/hardware_logs."""
    path = Path(os.environ.get(LOGS_ENV) or DEFAULT_LOGS)
    if not path.is_dir():
        raise FileNotFoundError(f"hardware logs not found at {path}: set {LOGS_ENV} to the hardware_logs folder")
    return path


# --- what the readers return ---------------------------------------------------------------------


@dataclass(eq=False)
class HeaterSeries:
    """One Klipper heater over one session, one sample per Stats line that reports it."""

    name: str
    t_s: np.ndarray  # host reactor time of the Stats line
    target_c: np.ndarray  # rounded to an integer by Klipper
    temp_c: np.ndarray  # the last raw 0.3 s sample, not smoothed
    pwm: np.ndarray  # 0..1, the last value sent to the MCU

    def segments(self, max_gap_s: float = STATS_GAP_S) -> list[HeaterSeries]:
        """The runs of samples without a gap longer than max_gap_s: compare or fit within these."""
        cuts = np.flatnonzero(np.diff(self.t_s) > max_gap_s) + 1
        columns = (np.split(a, cuts) for a in (self.t_s, self.target_c, self.temp_c, self.pwm))
        return [HeaterSeries(self.name, *parts) for parts in zip(*columns)]


@dataclass(eq=False)
class StatsLog:
    """Klipper Stats lines: one dict of heaters per session (klippy start or logged session id).

    meta: "klipper_version" (or None), "config" (the first config dump as {section: {option:
    text}}; SAVE_CONFIG may change it in later sessions) and "comments" (the file's header lines).
    """

    path: Path
    sessions: list[dict[str, HeaterSeries]]
    meta: dict


@dataclass(eq=False)
class HeattestLog:
    """An open-loop Klipper heater test: samples, the duty in force at each, the duty changes."""

    path: Path
    t_s: np.ndarray
    temp_c: np.ndarray
    pwm: np.ndarray  # 0..1
    pwm_events: list[tuple[float, float]]  # (t_s, pwm) where the duty changes


@dataclass
class M303Cycle:
    """What Marlin printed for one relay cycle; a partial capture may lack any field."""

    line_no: int
    heater: str  # "T" (hotend) or "B" (bed)
    bias: int | None = None  # on 0..255; Marlin's relay levels are (bias +- d) >> 1 on 0..127
    d: int | None = None
    min_c: float | None = None
    max_c: float | None = None
    ku: float | None = None
    tu_s: float | None = None
    kp: float | None = None
    ki: float | None = None
    kd: float | None = None
    rule: str | None = None  # "Classic PID" or "No overshoot"


class M303Status(NamedTuple):
    """One heater report line of the tuned heater."""

    line_no: int
    temp_c: float
    target_c: float  # nan where the line shows no target
    power: int  # 0..power_max of the log
    heater: str  # "T" or "B"


@dataclass(eq=False)
class M303Log:
    """Marlin (or Repetier) autotune console text: cycles, 2 s status reports, final gains.

    Status lines are 2 s apart during M303 but carry no time: their line numbers order them.
    skipped lists recognised lines that hold no usable data, with the reason.
    """

    path: Path
    commands: list[tuple[int, str]]  # (line_no, "M303 E0 C8 S210") as sent, if the capture shows them
    cycles: list[M303Cycle]
    status: list[M303Status]
    final_gains: tuple[float, float, float] | None  # the #define lines, else the last gains of a finished run
    rule: str | None  # the last cycle's tuning rule
    power_max: int  # full scale of the status power field
    firmware_hints: list[str]
    skipped: list[tuple[int, str]] = field(default_factory=list)
    idle_readings_c: list[float] = field(default_factory=list)  # the untuned heater's, where it has no target nor power


@dataclass(frozen=True)
class PidCalibrateResult:
    """Klipper PID gains and what they imply if PID_CALIBRATE's Ziegler-Nichols rule made them."""

    line_no: int
    source: str  # the collection's entry, e.g. "[1] https://github.com/Klipper3d/klipper/issues/603"
    heater: str | None
    kp: float
    ki: float
    kd: float
    max_power: float = 1.0

    @property
    def tu_s(self) -> float:
        """Relay period from Ki = Kp / (Tu / 2)."""
        return 2.0 * self.kp / self.ki

    @property
    def tu_from_kd_s(self) -> float:
        """Relay period from Kd = Kp Tu / 8; equals tu_s for genuine PID_CALIBRATE output."""
        return 8.0 * self.kd / self.kp

    @property
    def peak_to_peak_c(self) -> float:
        """Relay swing 2a from Kp = 0.6 * 4 max_power / (pi a) * 255."""
        return 8.0 * self.max_power * 0.6 * KLIPPER_PID_PARAM_BASE / (math.pi * self.kp)


@dataclass(eq=False)
class PlainLog:
    """A time series of temperature and heater duty."""

    path: Path
    t_s: np.ndarray
    temp_c: np.ndarray
    duty: np.ndarray  # 0..1
    duty_from_percent: bool  # the file gave duty in percent; duty was divided by 100


Log = StatsLog | HeattestLog | M303Log | PlainLog | list[PidCalibrateResult]


# --- shared line reading -------------------------------------------------------------------------


def _read_lines(path: str | Path, cut_last_line_ok: bool = False) -> list[tuple[int, str]]:
    """(line number, text) of each non-blank line, comments included.

    A last line without a newline means the file was cut mid-line: LogError, unless the format's
    writer leaves the newline out (cut_last_line_ok).
    """
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except UnicodeDecodeError as e:
        with open(path, "rb") as f:
            line_no = f.read()[: e.start].count(b"\n") + 1
        raise LogError(path, line_no, "not UTF-8 text") from None
    lines = text.split("\n")
    if lines[-1] == "":
        lines.pop()
    elif not cut_last_line_ok:
        raise LogError(path, len(lines), "the last line has no newline: the file was cut mid-line "
                       "(end it with a newline if the line is complete)")
    return [(no, line) for no, line in enumerate(lines, 1) if line.strip()]


def _is_comment(text: str) -> bool:
    return text == "#" or text.startswith("# ")


def _data(path: str | Path, lines: list[tuple[int, str]]) -> list[tuple[int, str]]:
    """The non-comment lines; none at all is an error."""
    data = [(no, text) for no, text in lines if not _is_comment(text)]
    if not data:
        raise LogError(path, lines[-1][0] if lines else 1, "no data lines")
    return data


def _number(path: str | Path, line_no: int, text: str, what: str,
            low: float = -math.inf, high: float = math.inf) -> float:
    """A finite float within [low, high], or LogError naming the line and the field."""
    try:
        value = float(text)
    except ValueError:
        raise LogError(path, line_no, f"{what}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise LogError(path, line_no, f"{what}: {text!r} is not a finite number")
    if not low <= value <= high:
        raise LogError(path, line_no, f"{what} = {text} is outside {low:g}..{high:g}")
    return value


def _integer(path: str | Path, line_no: int, text: str, what: str) -> int:
    value = _number(path, line_no, text, what)
    if value != int(value):
        raise LogError(path, line_no, f"{what}: {text!r} is not an integer")
    return int(value)


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _require_increasing(path: str | Path, line_nos: list[int], t_s: np.ndarray) -> None:
    """Time must increase from sample to sample."""
    bad = np.flatnonzero(np.diff(t_s) <= 0)
    if bad.size:
        i = bad[0] + 1
        raise LogError(path, line_nos[i], f"time {t_s[i]:g} s does not increase (previous sample: {t_s[i - 1]:g} s)")


def _csv_rows(path: str | Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """A CSV log's comment texts and its rows (header included) with line numbers; every row
    must be as wide as the first."""
    lines = _read_lines(path)
    comments = [text[2:] for no, text in lines if _is_comment(text)]
    rows = []
    for no, text in _data(path, lines):
        try:
            fields = next(csv.reader([text], strict=True))
        except csv.Error as e:
            raise LogError(path, no, f"not a CSV line: {e}") from None
        fields = [cell.strip() for cell in fields]
        if rows and len(fields) != len(rows[0][1]):
            raise LogError(path, no, f"{len(fields)} columns where the header has {len(rows[0][1])}")
        rows.append((no, fields))
    return comments, rows


def _time_series(path: str | Path, rows: list[tuple[int, list[str]]], names: tuple[str, str, str],
                 duty_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time, temperature and duty columns (duty within 0..duty_max); time must increase."""
    values = [(_number(path, no, t, names[0]), _number(path, no, temp, names[1]),
               _number(path, no, duty, names[2], 0.0, duty_max)) for no, (t, temp, duty) in rows]
    t_s, temp_c, duty = np.array(values, dtype=float).reshape(-1, 3).T
    _require_increasing(path, [no for no, _ in rows], t_s)
    return t_s, temp_c, duty


# --- Klipper Stats -------------------------------------------------------------------------------


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
        _require_increasing(path, line_nos, np.array(times))
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
    comments, rows = _csv_rows(path)
    (header_no, header), data = rows[0], rows[1:]
    heaters = [name.removesuffix("_target") for name in header[3::3]]
    expected = ["session", "t_host_s", "print_time_s"] + [f"{h}_{k}" for h in heaters for k in HEATER_KEYS]
    if header != expected:
        raise LogError(path, header_no, "the header is not session,t_host_s,print_time_s followed by "
                       "<heater>_target,<heater>_temp,<heater>_pwm per heater")
    stats_rows = []
    for no, fields in data:
        session = _integer(path, no, fields[0], "session")
        t_s = _number(path, no, fields[1], "t_host_s")
        if fields[2]:
            _number(path, no, fields[2], "print_time_s")
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
    return (_number(path, line_no, cells["target"], f"{name} target"),
            _number(path, line_no, cells["temp"], f"{name} temp"),
            _number(path, line_no, cells["pwm"], f"{name} pwm", 0.0, 1.0))


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
    lines = _read_lines(path)
    rows = []
    session = 0
    t_prev_s = -math.inf
    in_config = False
    config_lines: list[str] = []
    for no, text in lines:
        if _is_comment(text):
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
            t_s = _number(path, no, m[1], "Stats time")
            if t_s <= t_prev_s:
                session += 1
            t_prev_s = t_s
            heaters = _stats_heaters(path, no, m[2])
            if heaters:
                rows.append((no, session, t_s, heaters))
    texts = [text for _, text in lines]
    meta = {"klipper_version": _klipper_version(texts), "config": _config_sections(config_lines), "comments": []}
    return StatsLog(Path(path), _stats_sessions(path, rows), meta)


# --- Klipper heattest ----------------------------------------------------------------------------


def parse_heattest(path: str | Path) -> HeattestLog:
    """A Klipper heater test: PID_CALIBRATE WRITE_FILE=1 output ("pwm: <t> <duty>" events and
    "<t> <temp>" samples; duty before the first event is 0), or the project's CSV of it
    (t_s,temp_c,pwm with the duty in force at each sample)."""
    lines = _read_lines(path, cut_last_line_ok=True)  # Klipper writes no newline after the last line
    data = _data(path, lines)
    if data[0][1] == HEATTEST_CSV_HEADER:  # the CSV ends every line: read it again as CSV, strictly
        _, rows = _csv_rows(path)
        t_s, temp_c, pwm = _time_series(path, rows[1:], ("t_s", "temp_c", "pwm"), 1.0)
        changes = np.flatnonzero(np.diff(pwm, prepend=0.0))
        return HeattestLog(Path(path), t_s, temp_c, pwm, [(float(t_s[i]), float(pwm[i])) for i in changes])
    events, samples = [], []
    for no, text in data:
        if m := PWM_EVENT_RE.match(text):
            events.append((no, _number(path, no, m[1], "pwm time"), _number(path, no, m[2], "pwm", 0.0, 1.0)))
        elif len(parts := text.split()) == 2:
            samples.append((no, _number(path, no, parts[0], "time"), _number(path, no, parts[1], "temperature")))
        else:
            raise LogError(path, no, "expected '<time> <temp>' or 'pwm: <time> <duty>'")
    if not samples:
        raise LogError(path, data[-1][0], "no temperature samples")
    for found in (events, samples):
        _require_increasing(path, [no for no, _, _ in found], np.array([t for _, t, _ in found]))
    event_t_s = np.array([t for _, t, _ in events])
    event_pwm = np.array([0.0] + [v for _, _, v in events])
    t_s = np.array([t for _, t, _ in samples])
    pwm = event_pwm[np.searchsorted(event_t_s, t_s, side="right")]
    return HeattestLog(Path(path), t_s, np.array([c for _, _, c in samples]), pwm,
                       [(t, v) for _, t, v in events])


# --- plain CSV -----------------------------------------------------------------------------------


def parse_plain_csv(path: str | Path) -> PlainLog:
    """Three columns: time (s), temperature (C), heater duty. A header row names them, e.g.
    t_s,temp_c,duty or t_s,temp_c,duty_pct (percent, converted to 0..1); without a header the
    first row is data and duty must be in 0..1."""
    _, rows = _csv_rows(path)
    header_no, header = rows[0]
    if len(header) != 3:
        raise LogError(path, header_no, f"{len(header)} columns: expected time, temperature, duty")
    percent = False
    if not all(_is_number(cell) for cell in header):
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
    t_s, temp_c, duty = _time_series(path, rows, ("time", "temperature", duty_name), duty_max)
    return PlainLog(Path(path), t_s, temp_c, duty / duty_max, percent)


# --- Marlin M303 console text --------------------------------------------------------------------


def _console_text(text: str) -> str:
    """A console line without the host program's prefix."""
    return HOST_PREFIX_RE.sub("", text, count=1).strip()


def _status_sample(path: str | Path, line_no: int, temps: dict[str, tuple[float, float]], text: str,
                   heater: str) -> M303Status | None:
    """The tuned heater's reading in a status line, or None if the line lacks a power field it
    should have (Marlin and Repetier print @: and B@: whenever they show T and B)."""
    powers = dict(POWER_FIELD_RE.findall(text))
    both = "T" in temps and "B" in temps
    if (both and len(powers.keys() & {"@", "B@"}) < 2) or (not both and "@" not in powers):
        return None
    power_key = "B@" if heater == "B" and both else "@"
    return M303Status(line_no, *temps[heater], _integer(path, line_no, powers[power_key], f"{power_key} power"),
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


def parse_m303(path: str | Path) -> M303Log:
    """Marlin's M303 output as a host console shows it: bias/d/min/max lines (status text may follow
    on the same line), Ku/Tu (same or next line), the rule, Kp/Ki/Kd (one line or three), the
    #define lines, and the 2 s status reports of the tuned heater (T or B, from M303 E-1 or the
    report's shape). Repetier's output and M306 status traces read the same way."""
    lines = _data(path, _read_lines(path, cut_last_line_ok=True))  # pasted text: the status reader copes
    commands, cycles, status, skipped, hints = [], [], [], [], []
    idle_c: list[float] = []
    defines: dict[str, float] = {}
    finished = False
    heater = "T"

    def cycle(line_no: int, attr: str) -> M303Cycle:
        """The cycle a value belongs to: the last one, or a new one if the last has it already."""
        if not cycles or getattr(cycles[-1], attr) is not None:
            cycles.append(M303Cycle(line_no, heater))
        return cycles[-1]

    for no, raw in lines:
        text = _console_text(raw)
        for pattern, hint in FIRMWARE_HINTS:
            if pattern.search(text) and not any(h.startswith(hint) for h in hints):
                hints.append(f"{hint} (line {no})")
        finished = finished or "PID Autotune finished" in text
        if m := COMMAND_RE.match(text):
            commands.append((no, m[1].strip()))
            heater = "B" if BED_COMMAND_RE.search(m[1]) else "T"
            continue
        if m := DEFINE_RE.match(text):
            defines[m[2].lower()] = _number(path, no, m[3], f"DEFAULT_{m[1] or ''}K{m[2]}")
            continue
        rest = text
        if "bias:" in rest:
            if not (m := BIAS_RE.search(rest)):
                raise LogError(path, no, "a bias line without bias, d, min and max")
            c = M303Cycle(no, heater, _integer(path, no, m[1], "bias"), _integer(path, no, m[2], "d"),
                          _number(path, no, m[3], "min"), _number(path, no, m[4], "max"))
            cycles.append(c)
            rest = rest[m.end() :].strip()
        if "Ku:" in rest:
            if not (m := KU_RE.search(rest)):
                raise LogError(path, no, "a Ku line without Ku and Tu")
            c = cycle(no, "ku")
            c.ku, c.tu_s = _number(path, no, m[1], "Ku"), _number(path, no, m[2], "Tu", 0.0)
            rest = rest[m.end() :].strip()
        if rest in RULES:
            cycle(no, "rule").rule = rest
        elif GAIN_LINE_RE.match(rest):
            for k, value in GAIN_RE.findall(rest):
                setattr(cycle(no, "k" + k.lower()), "k" + k.lower(), _number(path, no, value, "K" + k))
        elif STATUS_RE.match(rest):
            if not TEMP_FIELD_RE.match(rest):
                raise LogError(path, no, f"a status line without a temperature after {rest[:2]}")
            temps = {key: (_number(path, no, temp, f"{key} temperature"),
                           _number(path, no, target, f"{key} target") if target else math.nan)
                     for key, temp, target in TEMP_FIELD_RE.findall(rest)}
            if len(temps) == 1:
                heater = next(iter(temps))
            elif (reading := _idle_reading(temps, rest, heater)) is not None:
                idle_c.append(reading)
            sample = _status_sample(path, no, temps, rest, heater)
            if sample is None:
                skipped.append((no, INCOMPLETE_STATUS))
            else:
                status.append(sample)
    if not (cycles or status or defines):
        raise LogError(path, lines[-1][0], "no autotune output: no bias, Ku/Tu, gain, #define or status line")
    last = cycles[-1] if cycles else None
    if len(defines) == 3:
        final_gains = (defines["p"], defines["i"], defines["d"])
    elif finished and last and None not in (last.kp, last.ki, last.kd):
        final_gains = (last.kp, last.ki, last.kd)
    else:
        final_gains = None
    power_max = REPETIER_POWER_MAX if any(h.startswith(REPETIER_HINT) for h in hints) else MARLIN_POWER_MAX
    rule = next((c.rule for c in reversed(cycles) if c.rule), None)
    return M303Log(Path(path), commands, cycles, status, final_gains, rule, power_max, hints, skipped, idle_c)


# --- Klipper PID_CALIBRATE results ---------------------------------------------------------------


def parse_pid_calibrate_results(path: str | Path) -> list[PidCalibrateResult]:
    """Klipper PID gains in any of the forms the results collection holds: "Autotune: final:
    Kp=.. Ki=.. Kd=..", "PID parameters: pid_Kp=.. pid_Ki=.. pid_Kd=..", "pid_kp = .." (one line
    each or on one line), also in the comment table of SAVE_CONFIG values. An entry heading
    "# [n] <url> ..." names the source; "# <label>:" lines and a "<file>.csv" name refine it, a
    heater name (extruder, heater_bed) or "max_power x" on a line applies to the gains after it."""
    lines = _read_lines(path)
    results = []
    entry, label, log_file, heater = "", None, None, None
    gains: dict[str, float] = {}
    gains_no = 0  # the line of the first gain still waiting for the others
    for no, raw in lines:
        comment = _is_comment(raw)
        text = raw[2:].strip() if comment else _console_text(raw)
        if comment and (m := PID_HEADING_RE.match(text)):
            if gains:
                raise LogError(path, gains_no, INCOMPLETE_GAINS)
            entry, label, log_file, heater = " ".join(filter(None, (f"[{m[1]}]", m[2]))), None, None, None
        if comment and text.endswith(":") and not PID_HEADING_RE.match(text):
            label = text[:-1]
        if text.split(" ", 1)[0].endswith(".csv"):
            log_file = text.split(" ", 1)[0]
        if m := KLIPPER_HEATER_RE.search(text):
            heater = m[1]
        max_power = float(m[1]) if (m := MAX_POWER_RE.search(text)) else 1.0
        if comment and "pid_kp" not in text.lower():
            continue  # prose about gains ("Tu = 2*Kp/Ki"); the comment table holds pid_kp = .. values
        for k, value in GAIN_RE.findall(text):
            k = k.lower()
            if k in gains:
                raise LogError(path, no, f"K{k} again before the set of Kp, Ki, Kd is complete")
            gains_no = gains_no if gains else no
            gains[k] = _number(path, no, value, f"K{k}", 0.0)
            if len(gains) == 3:
                source = " ".join(s for s in (entry, log_file, label) if s)
                results.append(PidCalibrateResult(no, source, heater, gains["p"], gains["i"], gains["d"], max_power))
                gains = {}
    if gains:
        raise LogError(path, gains_no, INCOMPLETE_GAINS)
    if not results:
        raise LogError(path, lines[-1][0] if lines else 1, "no PID gains")
    return results


# --- any of them ---------------------------------------------------------------------------------


def load_log(path: str | Path) -> Log:
    """Read a log of any kind above, told apart by its content; LogError says why a file is none."""
    data = _data(path, _read_lines(path, cut_last_line_ok=True))
    first_no, first = data[0]
    if first.startswith("session,t_host_s,"):
        return parse_klipper_stats_csv(path)
    if first == HEATTEST_CSV_HEADER or first.startswith("pwm: "):
        return parse_heattest(path)
    texts = [_console_text(text) for _, text in data]
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
