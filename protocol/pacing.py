"""The printer's clock against the wall: speeds and the ``Pacer`` that turns wall time into virtual time.

Speed N runs the clock at N x wall time; ``max`` runs it free while a command executes (M109,
M190, M303, G4, M400) and, with an idle speed of 0, stops it while the printer waits for the host
(that for deterministic tests: a real printer's clock never stops). The transports and the
``twin://`` handler call ``Pacer.advance()`` between serving their host.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Literal

from protocol.printer import VirtualPrinter
from twin.linear import TICK_S

MAX: Literal["max"] = "max"
Speed = float | Literal["max"]
# Idle clock speed for twin-serial and twin://: real time. OctoPrint's and Pronterface's graphs,
# timeouts and heat-up expectations are in wall seconds, so an idle printer behaves as the real
# one does; the long waits (M109, M190, M303, G4, M400) are where speed matters, and they run free.
DEFAULT_IDLE_SPEED = 1.0

PACE_S = 0.01  # speed N: wall seconds between clock updates, the timing resolution a host sees
CATCH_UP_S = 0.05  # speed N: one update runs at most this much wall time's worth of virtual time
FREE_STEP_S = 1.0  # speed max: virtual seconds per update (M109 reports once a second)
# The fastest speed N taken: a thousand times real time is 50 virtual seconds per paced step, beyond
# what the twin computes in CATCH_UP_S of wall time (``max`` is the way to say "as fast as it goes").
SPEED_MAX = 1000.0


def default_idle_speed(speed: Speed) -> float:
    """The idle clock when none is given: DEFAULT_IDLE_SPEED under ``--speed max``, else the same
    N as ``--speed N`` (one speed for the whole session, as ``--speed N`` always meant)."""
    return DEFAULT_IDLE_SPEED if speed == MAX else speed


def parse_idle_speed(text: str) -> float:
    """A factor of real time >= 0; 0 is the host-driven clock (stopped while the host is idle)."""
    try:
        speed = float(text)
    except ValueError:
        speed = math.nan
    if not (math.isfinite(speed) and 0 <= speed <= SPEED_MAX):
        raise ValueError(f"idle speed must be a number in 0..{SPEED_MAX:g} (1 = real time, 0 = host-driven clock), "
                         f"not {text!r}")
    return speed


def parse_speed(text: str) -> Speed:
    """``max``, or a positive factor of real time (``1`` is real time)."""
    if text == MAX:
        return MAX
    try:
        speed = float(text)
    except ValueError:
        speed = math.nan
    if not (math.isfinite(speed) and 0 < speed <= SPEED_MAX):
        raise ValueError(f"speed must be 'max' or a positive number up to {SPEED_MAX:g} (1 = real time), not {text!r}")
    return speed


class Pacer:
    """Turns wall time into the printer's virtual time: the clock that keeps running.

    While a command executes (M109, M190, M303, G4, M400, a G1 waiting for the planner) the
    clock runs at ``speed``: ``max`` runs it free, a virtual second per call, so such commands
    end in seconds; N runs it at N x the wall time. Otherwise it runs at ``idle_speed`` x the
    wall time, so a target set with M104 heats and M155 reports come while the host only
    listens. ``idle_speed`` 0 is the host-driven clock: it stops while the printer waits for the
    host (at ``max``, moves left in the planner still run free), which makes a session a pure
    function of the bytes sent: the deterministic mode for tests. A paced step runs at most
    CATCH_UP_S of wall time's worth, so a twin slower than asked still serves its host between.
    """

    def __init__(self, printer: VirtualPrinter, speed: Speed = MAX, idle_speed: float | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.printer = printer
        self.speed = speed
        self.idle_speed = default_idle_speed(speed) if idle_speed is None else idle_speed
        self.clock = clock
        self._accounted_s = clock()  # wall time already turned into virtual time
        if not self.host_driven:
            printer.wall_clock = clock  # reports and keepalives: at most once per wall interval too

    def __repr__(self) -> str:
        return f"Pacer(speed {self.speed}, idle speed {self.idle_speed:g})"

    @property
    def host_driven(self) -> bool:
        """The clock stops while the printer waits for the host (``idle_speed`` 0)."""
        return self.idle_speed == 0

    @property
    def runs_free(self) -> bool:
        """The next advance() runs the clock free (one FREE_STEP_S of virtual time)."""
        return self.speed == MAX and (self.busy or self.host_driven)

    @property
    def busy(self) -> bool:
        """A command executes, or bytes are still arriving: the clock runs at ``speed``."""
        return self.printer.executing or self.printer.receiving

    def advance(self) -> float | None:
        """Run the clock as far as the speeds allow now.

        Returns how long the caller may wait for the host before the next call: 0 when there
        is more to run at once, None when nothing happens until the host sends something.
        """
        printer = self.printer
        if self.runs_free:
            return self._run_free()
        speed = self.idle_speed
        if self.busy and self.speed != MAX:  # at max, runs_free took it above
            speed = float(self.speed)
        now_s = self.clock()
        if speed == 0:  # host-driven and idle: the clock waits, and owes the wall nothing
            self._accounted_s = now_s
            return None
        due_s = (now_s - self._accounted_s) * speed
        step_s = min(due_s, CATCH_UP_S * speed)
        if step_s > 0:
            printer.run_for(step_s)
            self._accounted_s += step_s / speed
        return 0.0 if due_s > step_s else PACE_S

    def _run_free(self) -> float | None:
        printer = self.printer
        start_s = printer.time_s
        if self.host_driven:
            printer.run_until_idle(FREE_STEP_S)
        else:
            printer.run_while_busy(FREE_STEP_S)
        self._accounted_s = self.clock()  # free time owes the wall nothing
        # It returns early once the printer waits for the host; a halted board runs nothing.
        still_busy = printer.time_s - start_s > FREE_STEP_S - TICK_S / 2 and not printer.halted
        if still_busy:
            return 0.0
        return None if self.host_driven else PACE_S
