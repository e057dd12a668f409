"""The printer's mechanics behind the steppers' pins: where each stepper has gone by an MCU clock,
from the steps the MCU gave it, and whether that presses an endstop.

Steps follow src/stepper.c: a move (interval, count, add) after the last step at clock T steps at
T + interval, then each step ``add`` clocks longer than the one before, so step k of the move is at
T + k * interval + add * k (k - 1) / 2. Each step goes one step the way the direction pin said when
the move was queued: the MCU's position counts +1 for dir 1 (what ``stepper_get_position``
reports), and the stepper's millimetres are klippy's (its ``!`` on dir_pin flips them).

A switch sits on a rail (user_config.AxisPins): the rail's coordinate is a sum of its steppers'
travels through the config's kinematics (cartesian x = stepper_x; corexy x = (a + b) / 2), from
the middle of the rail's travel where the printer starts, with the switch open; it closes where
the coordinate reaches position_endstop from the inside, as on a printer whose switch sits at
the end klippy's config names.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from protocol.klipper_mcu.user_config import AxisPins, RailPins, StepperPins


@dataclass
class Move:
    start_clock: int  # the step before the first (T)
    interval: int
    count: int
    add: int
    direction: int  # +1 or -1

    def step_clock(self, k: int) -> int:
        """The clock of step k (1..count)."""
        return self.start_clock + k * self.interval + self.add * k * (k - 1) // 2

    def end_clock(self) -> int:
        return self.step_clock(self.count)

    def steps_by(self, clock: int) -> int:
        """How many of its steps have come by ``clock``."""
        if clock < self.step_clock(1):
            return 0
        if clock >= self.step_clock(self.count):
            return self.count
        a, b, c = self.add / 2, self.interval - self.add / 2, self.start_clock - clock
        k = int(-c / b) if a == 0 else int((-b + math.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a))
        k = min(max(k, 0), self.count)
        while k < self.count and self.step_clock(k + 1) <= clock:
            k += 1
        while k > 0 and self.step_clock(k) > clock:
            k -= 1
        return k


@dataclass
class Carriage:
    """One stepper's steps over time (its queued moves; the position before them)."""

    stepper: StepperPins | None = None  # None: a stepper the config does not describe (its mm are unknown)
    position: int = 0  # MCU steps before the first move in ``moves``
    moves: deque[Move] = field(default_factory=deque)

    def queue(self, move: Move, now: int) -> None:
        """A new move (the moves that ended by ``now`` are folded into ``position`` first)."""
        while self.moves and self.moves[0].end_clock() <= now:
            done = self.moves.popleft()
            self.position += done.direction * done.count
        self.moves.append(move)

    def steps_at(self, clock: int) -> int:
        """The MCU's step count at ``clock``."""
        return self.position + sum(m.direction * m.steps_by(clock) for m in self.moves)

    def stop(self, clock: int) -> None:
        """stepper_stop on a trigger: the steps after ``clock`` never come."""
        self.position = self.steps_at(clock)
        self.moves.clear()

    def last_step_clock(self) -> int | None:
        return self.moves[-1].end_clock() if self.moves else None

    def mm_per_step(self) -> float:
        """klippy's millimetres per MCU step (+1 in the MCU's count); 0: a stepper the config does not describe."""
        if self.stepper is None:
            return 0.0
        return (-1.0 if self.stepper.dir_inverted else 1.0) * self.stepper.step_mm

    def travel_mm(self, clock: int) -> float:
        """klippy's millimetres this stepper has gone since the twin started."""
        return self.steps_at(clock) * self.mm_per_step()


class _Timeline:
    """A carriage's queued moves, frozen for many look-ups: its steps at a clock in O(log moves)."""

    def __init__(self, carriage: Carriage):
        self.moves = list(carriage.moves)
        self.ends = [m.end_clock() for m in self.moves]
        self.before = [carriage.position]
        for move in self.moves:
            self.before.append(self.before[-1] + move.direction * move.count)
        self.mm_per_step = carriage.mm_per_step()

    def travel_mm(self, clock: int) -> float:
        i = bisect.bisect_right(self.ends, clock)  # the moves before i ended by ``clock``; moves never overlap
        steps = self.before[i] + (self.moves[i].direction * self.moves[i].steps_by(clock) if i < len(self.moves) else 0)
        return steps * self.mm_per_step


class Rail:
    """A coordinate of the printer: the middle of its travel plus its steppers' travels through the kinematics."""

    def __init__(self, pins: RailPins, carriage: Callable[[str], Carriage]):
        self.start_mm = (pins.position_min_mm + pins.position_max_mm) / 2
        self.terms = [(carriage(stepper.step_pin), weight) for stepper, weight in pins.terms]

    def __repr__(self) -> str:
        return f"Rail(from {self.start_mm:g} mm, {len(self.terms)} steppers)"

    def at_mm(self, clock: int) -> float:
        return self.start_mm + sum(weight * c.travel_mm(clock) for c, weight in self.terms)

    def moves_with(self, carriage: Carriage) -> bool:
        return any(c is carriage for c, _ in self.terms)

    def first_clock(self, clock: int, reached: Callable[[float], bool]) -> int | None:
        """The first clock from ``clock`` on at which the coordinate is ``reached``, as far as the queued moves go (None:
        not within them). Between two clocks where a move of any of its steppers starts or ends, each stepper
        goes one way, so a coordinate through weights of one sign, or one stepper, is monotone there and the
        first clock is found by bisection (a diagonal of mixed signs is off by at most a step's quantisation)."""
        timelines = [(_Timeline(c), weight) for c, weight in self.terms]

        def reached_at(at: int) -> bool:
            return reached(self.start_mm + sum(weight * t.travel_mm(at) for t, weight in timelines))

        if reached_at(clock):
            return clock
        edges = sorted({edge for c, _ in self.terms for m in c.moves
                        for edge in (m.step_clock(1), m.end_clock()) if edge > clock})
        low = clock
        for edge in edges:
            if reached_at(edge):
                high = edge
                while high - low > 1:
                    mid = (low + high) // 2
                    if reached_at(mid):
                        high = mid
                    else:
                        low = mid
                return high
            low = edge
        return None


class Switch:
    """An endstop on a rail: pressed where the rail's coordinate is at or past position_endstop."""

    def __init__(self, axis: AxisPins, carriage: Callable[[str], Carriage]):
        self.axis, self.rail = axis, Rail(axis.rail, carriage)

    def __repr__(self) -> str:
        return f"Switch({self.axis.endstop.name} of {self.axis.section}, {self.rail!r})"

    def pressed(self, clock: int) -> bool:
        return self._reached(self.rail.at_mm(clock))

    def _reached(self, at_mm: float) -> bool:
        axis = self.axis
        return at_mm >= axis.position_endstop_mm if axis.homes_positive else at_mm <= axis.position_endstop_mm

    def pressed_from(self, clock: int) -> int | None:
        """The first clock from ``clock`` on at which it is pressed, as far as the queued moves go."""
        return self.rail.first_clock(clock, self._reached)

    def moves_with(self, carriage: Carriage) -> bool:
        return self.rail.moves_with(carriage)
