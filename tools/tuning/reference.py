"""The gains the printer already has: the answer a tune must beat.

A log states them where it can: an M303 capture's last printed Kp/Ki/Kd (or its ``#define DEFAULT_K..``
lines), a klippy.log's config dump (``pid_Kp``/``pid_Ki``/``pid_Kd`` of the heater's section), a
PID_CALIBRATE result's gains. A user states them with ``--current-gains``: ``P,I,D``, Marlin's
``M301 P.. I.. D..`` (or M304, or M503's echo of it), or Klipper's ``pid_Kp=.. pid_Ki=.. pid_Kd=..``.
Marlin's M301/M304 and Klipper's pid_K* share one scale (tools/tuning/gains.py), so one parser serves.
Gains of 0, 0, 0 (an M303 of fewer than three cycles prints them) are no gains a printer runs on.

    printer = from_log(load_log("m303.txt"), "extruder")   # PrinterGains(gains, source) or None
    given = parse_gains("M301 P22.2 I1.08 D114")
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from tools.logs import Log, M303Log, PidCalibrateResult, StatsLog
from tools.tuning.gains import Gains

MARLIN_KEY = {"extruder": "T", "heater_bed": "B"}
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_MARLIN_RE = re.compile(rf"\bP\s*({_NUMBER})\s+I\s*({_NUMBER})\s+D\s*({_NUMBER})", re.IGNORECASE)
_KLIPPER_RE = re.compile(rf"pid_?kp\s*[=:]\s*({_NUMBER}).*?pid_?ki\s*[=:]\s*({_NUMBER}).*?pid_?kd\s*[=:]\s*({_NUMBER})",
                         re.IGNORECASE | re.DOTALL)
_PLAIN_RE = re.compile(rf"^\s*({_NUMBER})\s*[, ]\s*({_NUMBER})\s*[, ]\s*({_NUMBER})\s*$")


@dataclass(frozen=True)
class PrinterGains:
    """The printer's own gains and where they were read."""

    gains: Gains
    source: str


def parse_gains(text: str, flag: str = "--current-gains") -> Gains:
    """Gains from ``P,I,D``, ``M301 P.. I.. D..`` or ``pid_Kp=.. pid_Ki=.. pid_Kd=..``; ValueError naming
    the flag otherwise."""
    for pattern in (_PLAIN_RE, _MARLIN_RE, _KLIPPER_RE):
        if m := pattern.search(text):
            try:
                return Gains(*(float(v) for v in m.groups()))
            except ValueError as exc:
                raise ValueError(f"{flag} {text!r}: {exc}") from None
    raise ValueError(f"{flag} {text!r}: give P,I,D (e.g. 22.2,1.08,114), 'M301 P22.2 I1.08 D114' or "
                     "'pid_Kp=22.2 pid_Ki=1.08 pid_Kd=114'")


def from_log(log: Log, heater: str, entry: int | None = None) -> PrinterGains | None:
    """The printer's gains the log states for the heater (a PID_CALIBRATE collection: the ``entry`` fitted,
    default the first), or None where it states none."""
    found: tuple[tuple[float, float, float], str] | None = None
    if isinstance(log, M303Log):
        found = _m303_gains(log, heater)
    elif isinstance(log, StatsLog):
        config = log.meta["config"].get(heater, {})
        if config.get("control", "pid") == "pid" and all(k in config for k in ("pid_kp", "pid_ki", "pid_kd")):
            found = ((float(config["pid_kp"]), float(config["pid_ki"]), float(config["pid_kd"])),
                     f"[{heater}] pid_Kp/Ki/Kd in the log's config dump")
    elif isinstance(log, list) and log:
        result: PidCalibrateResult = log[entry or 0]
        found = (result.kp, result.ki, result.kd), f"the PID_CALIBRATE result of entry {entry or 0}"
    if found is None or not any(found[0]):
        return None
    return PrinterGains(Gains(*found[0]), found[1])


def _m303_gains(log: M303Log, heater: str) -> tuple[tuple[float, float, float], str] | None:
    """The last Kp/Ki/Kd the capture printed for the heater (a partial run's last gains: what its printer
    would have stored), else its #define DEFAULT_K lines."""
    printed = [(c.kp, c.ki, c.kd) for c in log.cycles_of(MARLIN_KEY[heater])
               if c.kp is not None and c.ki is not None and c.kd is not None]
    if printed:
        return printed[-1], "the last Kp/Ki/Kd the capture printed"
    if log.final_gains is None or any(c.kp is not None for c in log.cycles):  # the gains are another heater's
        return None
    return log.final_gains, "the capture's #define DEFAULT_K lines"
