"""The ranges a value may take where it enters the twin (the Python API, scenario files, the CLIs,
``twin://``), and the one check that says which value is wrong.

Two kinds of range: what is physically possible (the API: an ambient above absolute zero, a run
shorter than Marlin's millis() wrap, a trace that fits in memory), and what is plausible where a
person types a number (scenario files and the CLIs: an ambient of 400 C there is a typo). And the
kind of file an input path must name: a regular one (a FIFO would block its reader).
"""

from __future__ import annotations

import math
import numbers
import os
import stat
from pathlib import Path

from firmware_port.user_error import UserError as UserError  # where every command catches it

ABSOLUTE_ZERO_C = -273.15
HEATER_MAX_C = 400.0  # the hottest setpoint the twin takes; firmware clamps lower (Marlin: hotend 260, bed 140)
TARGET_RANGE_C = (0, int(HEATER_MAX_C))  # setpoints (whole degrees, as M104/M140 take them)
# The API: any world a heater can work in, from just above absolute zero to its hottest setpoint.
PHYSICAL_RANGE_C = (ABSOLUTE_ZERO_C, HEATER_MAX_C)
# Typed by a person (scenario files, --ambient): a cold garage to a heated industrial chamber.
AMBIENT_RANGE_C = (-40.0, 120.0)
INITIAL_RANGE_C = (-40.0, HEATER_MAX_C)
DURATION_MAX_S = 2**32 / 1000  # Marlin's millis() is a uint32: it wraps after 49.7 days
NOISE_MAX_LSB = 100.0  # ADC noise beyond this is no sensor, it is a broken wire
SEED_MAX = 2**63 - 1  # a lane's seed is an int64 (twin/lane_noise.py)
# A run's records in memory: beyond this a run is refused rather than let grow until the machine
# swaps; record fewer rows (``record_every_s``, twin-sim --record-every) or none (``record=False``).
TRACE_MAX_BYTES = 2**31
THREADS_ENV = "HEATER_TWIN_THREADS"  # how many threads a batch spreads its lanes over (twin/batch.py)


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def checked(name: str, value: object, low: float = -math.inf, high: float = math.inf, unit: str = "", *,
            above: bool = False) -> float:
    """``value`` as a float if it is a finite number in low..high (``above``: strictly above low), else
    UserError naming ``name``: the one-line message of a bad argument."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise UserError(f"{name}={_show(value)}: expected a number")
    try:
        number = float(value)
    except OverflowError:  # an int beyond float's range
        number = math.inf
    if not math.isfinite(number):
        raise UserError(f"{name}={_show(value)}: must be a finite number")
    if number < low or number > high or (above and number == low):
        bounds = ([f"{'>' if above else '>='} {low:g}"] if low > -math.inf else []) + \
            ([f"<= {high:g}"] if high < math.inf else [])
        raise UserError(f"{name}={_show(value)}: must be {' and '.join(bounds)}{' ' + unit if unit else ''}")
    return number


def checked_seed(name: str, value: object) -> int:
    """A seed: a whole number in 0..SEED_MAX; UserError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= int(value) <= SEED_MAX:
        raise UserError(f"{name}={_show(value)}: must be a whole number in 0..2**63-1")
    return int(value)


def check_trace_bytes(horizon_s: float, trace_bytes: float, remedy: str) -> None:
    """Refuse a run whose records would outgrow TRACE_MAX_BYTES; ``remedy`` says what to do instead."""
    if trace_bytes > TRACE_MAX_BYTES:
        raise UserError(f"a run to {horizon_s:g} s would keep about {trace_bytes / 2**30:.3g} GiB of records, "
                         f"more than {TRACE_MAX_BYTES / 2**30:g} GiB: {remedy}")


def check_regular_file(path: str | Path) -> None:
    """UserError (what it is, for the caller to prefix with the path) if ``path`` names anything but a
    regular file (a FIFO blocks its reader, a device never ends); a path that does not exist is left for
    open() to report."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a device or a socket"
        raise UserError(f"{kind}, not a regular file")
