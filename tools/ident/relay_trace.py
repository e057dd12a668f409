"""An M303 capture's 2 s status trace made fit for identification: the relay's target, its switch
instants between the status lines, and an ambient temperature.

Marlin's relay (Marlin/src/module/temperature.cpp, PID_autotune) switches the heater off when
the reading rises above the target and on when it falls below (each half-cycle at least 5 s), on
its own 164 ms readings; the status lines show the power only every 2 s, so a switch can appear up
to 2 s late. Between the last status line at one level and the first at the other, the reading
crosses the target: interpolated linearly there, that crossing is the switch instant, inserted as
an extra, unobserved, sample (its reading is not compared, only its duty used).
"""

from __future__ import annotations

import re

import numpy as np

from tools.logs import BED_COMMAND_RE, M303Log

TARGET_RE = re.compile(r"\bS(\d+(?:\.\d*)?)")  # M303 ... S210: the target in C
AMBIENT_PRIOR_C = 25.0  # a room, when the capture shows no idle heater to read it from
IDLE_MAX_ABOVE_PRIOR_C = 15.0  # an "idle" heater warmer than prior + this still holds heat: not ambient


def command_target_c(log: M303Log, heater_key: str, before_line: int) -> float | None:
    """The S value of the last M303 command before a line, if it tuned this heater ("T" or "B")."""
    for line_no, command in reversed(log.commands):
        if line_no < before_line and command.startswith("M303"):
            if ("B" if BED_COMMAND_RE.search(command) else "T") != heater_key:
                return None
            return float(m[1]) if (m := TARGET_RE.search(command)) else None
    return None


def estimate_target_c(temp_c: np.ndarray, on: np.ndarray) -> float | None:
    """The relay's target from the trace: between two status lines where the heater went off the
    reading rose through it, where it came on the reading fell through it; the median of those
    interval midpoints, rounded to whole C (M303 S takes whole degrees). None without a switch."""
    switches = np.flatnonzero(on[:-1] != on[1:])
    if not switches.size:
        return None
    return float(np.rint(np.median((temp_c[switches] + temp_c[switches + 1]) / 2.0)))


def switch_instants(t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray,
                    target_c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t_s, temp_c, duty, observed) with a sample inserted at each reconstructed switch: the
    duty changes there instead of at the next status line. Where the two readings do not straddle
    the target (a half-cycle held by the 5 s minimum, noise), the switch is put midway."""
    on = duty > duty.min() if np.ptp(duty) else np.zeros(len(duty), bool)
    times, temps, duties, observed = [t_s[0]], [temp_c[0]], [duty[0]], [True]
    for i in range(1, len(t_s)):
        if on[i] != on[i - 1]:
            a, b = temp_c[i - 1], temp_c[i]
            frac = (target_c - a) / (b - a) if (a - target_c) * (b - target_c) < 0 else 0.5
            times.append(t_s[i - 1] + frac * (t_s[i] - t_s[i - 1]))
            temps.append(a + frac * (b - a))
            duties.append(duty[i])
            observed.append(False)
        times.append(t_s[i])
        temps.append(temp_c[i])
        duties.append(duty[i])
        observed.append(True)
    return np.array(times), np.array(temps), np.array(duties), np.array(observed)


def ambient_reading_c(log: M303Log) -> float | None:
    """The untuned heater's reading where it is idle (no target, no power) and near room
    temperature (a bed at rest reads the room), or None where the capture shows none."""
    idle = [c for c in log.idle_readings_c if c <= AMBIENT_PRIOR_C + IDLE_MAX_ABOVE_PRIOR_C]
    return float(np.median(idle)) if idle else None


def ambient_hint_c(log: M303Log) -> float:
    """``ambient_reading_c``, else AMBIENT_PRIOR_C."""
    reading = ambient_reading_c(log)
    return AMBIENT_PRIOR_C if reading is None else reading
