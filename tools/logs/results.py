"""What the log readers return: Klipper heater series and Stats sessions, heattests, M303 cycles
and status reports, PID_CALIBRATE gains, plain time series; ``Log`` is any of them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

# Klipper (klippy/extras/statistics.py) writes a Stats line every 1 s of host time while a heater
# is active or a print runs. More than 5 s without one is a gap: heaters idle and cold, klippy
# busy or restarting; the heater's state in between is unknown.
STATS_GAP_S = 5.0

# Klipper PID_CALIBRATE (pid_calibrate.py): Kp = 0.6 Ku 255, Ti = Tu / 2, Td = Tu / 8, and
# Ku = 4 max_power / (pi a) for a relay swing of peak-to-peak 2a.
KLIPPER_PID_PARAM_BASE = 255.0


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
    heater: str  # "T" (hotend), "B" (bed), or "?" where nothing before it in the capture says which
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


class M303Run(NamedTuple):
    """One autotune run of a capture (from an M303 command or "PID Autotune start" to the next): the line it
    starts at, the heater its lines say it tunes ("T", "B", or "?" where none says) and the line that says it."""

    line_no: int
    heater: str
    evidence: str  # e.g. "the M303 command (line 5)"; "" where no line says


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
    runs: list[M303Run] = field(default_factory=list)

    def run_at(self, line_no: int) -> M303Run | None:
        """The run a line belongs to (None before the first)."""
        return next((run for run in reversed(self.runs) if run.line_no <= line_no), None)

    def cycles_of(self, key: str) -> list[M303Cycle]:
        """The cycles of heater "T" or "B", with those the capture does not attribute ("?")."""
        return [c for c in self.cycles if c.heater in (key, "?")]


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
