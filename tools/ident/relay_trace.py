"""An M303 capture's 2 s status trace made fit for identification: the relay's target, its switch
instants between the status lines, and an ambient temperature.

The relay's target is the M303 command's S where the capture shows the command; else the data say
it (``relay_target_c``): Marlin resets its min to the target when the heater switches on and its
max to the target when it switches off, so every printed cycle's min..max holds the target, and M303
takes whole degrees. Of the whole degrees every cycle holds, the one nearest the status trace's
switches (``estimate_target_c``), else nearest the middle of that range, is the target.

Marlin's relay (Marlin/src/module/temperature.cpp, PID_autotune) switches the heater off when
the reading rises above the target and on when it falls below (each half-cycle at least 5 s), on
its own 164 ms readings; the status lines show the power only every 2 s, so a switch can appear up
to 2 s late. Between the last status line at one level and the first at the other, the reading
crosses the target: interpolated linearly there, that crossing is the switch instant, inserted as
an extra, unobserved, sample (its reading is not compared, only its duty used).
"""

from __future__ import annotations

import math
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


def relay_target_c(log: M303Log, heater_key: str, first_line: int,
                   switches: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[float, str] | None:
    """The relay's target of a heater's ("T" or "B") run at first_line, and where it comes from (module
    docstring); ``switches`` the run's status trace (readings, heater on) where there is one. None where the
    capture shows no command, no cycle of the run with min and max, and no switch."""
    if (command_c := command_target_c(log, heater_key, first_line)) is not None:
        return command_c, "from the M303 command"
    switched_c = None if switches is None else estimate_target_c(*switches)
    run = log.run_at(first_line)
    extremes = [(c.min_c, c.max_c) for c in log.cycles_of(heater_key)
                if c.min_c is not None and c.max_c is not None and log.run_at(c.line_no) == run]
    if not extremes:
        return None if switched_c is None else (switched_c, "found in the data: the status trace's switches")
    low_c, high_c = max(low for low, _ in extremes), min(high for _, high in extremes)
    if math.ceil(low_c) > math.floor(high_c):  # no whole degree within every cycle: runs at other targets?
        return float(np.rint(np.median([(low + high) / 2.0 for low, high in extremes]))), (
            "found in the data: the whole degree nearest the middle of the printed cycles (no whole degree lies "
            "within every cycle's min..max)")
    near_c, near_what = ((low_c + high_c) / 2.0, "its middle") if switched_c is None else \
        (switched_c, "the status trace's switches")
    target_c = float(min(max(np.rint(near_c), math.ceil(low_c)), math.floor(high_c)))
    return target_c, (f"found in the data: within {low_c:.2f}..{high_c:.2f} C, where every printed cycle's min..max "
                      f"holds it, the whole degree nearest {near_what}")


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
