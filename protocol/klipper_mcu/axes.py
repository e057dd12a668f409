"""The printer's mechanics behind a stepper's pins: where its carriage is at an MCU clock, from the
steps the MCU gave it, and whether that presses its endstop.

Steps follow src/stepper.c: a move (interval, count, add) after the last step at clock T steps at
T + interval, then each step ``add`` clocks longer than the one before, so step k of the move is at
T + k * interval + add * k (k - 1) / 2. Each step goes one step the way the direction pin said when
the move was queued: the MCU's position counts +1 for dir 1 (what ``stepper_get_position``
reports), and the carriage's millimetres are klippy's (its ``!`` on dir_pin flips them).

A carriage starts at the middle of its travel, with its endstop open; the endstop closes where the
carriage reaches position_endstop from the inside, as on a printer whose switch sits at the end
klippy's config names.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from protocol.klipper_mcu.user_config import AxisPins


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

    pins: AxisPins | None  # None: a stepper with no endstop on this MCU (an extruder)
    position: int = 0  # MCU steps before the first move in ``moves``
    moves: deque = field(default_factory=deque)

    def steps_at(self, clock: int) -> int:
        """The MCU's step count at ``clock`` (moves that ended by then are folded in)."""
        while self.moves and self.moves[0].step_clock(self.moves[0].count) <= clock:
            move = self.moves.popleft()
            self.position += move.direction * move.count
        return self.position + sum(m.direction * m.steps_by(clock) for m in self.moves)

    def stop(self, clock: int) -> None:
        """stepper_stop on a trigger: the steps after ``clock`` never come."""
        self.position = self.steps_at(clock)
        self.moves.clear()

    def last_step_clock(self) -> int | None:
        return self.moves[-1].step_clock(self.moves[-1].count) if self.moves else None

    def at_mm(self, steps: int) -> float:
        """klippy's millimetres at an MCU step count (the carriage starts mid-travel)."""
        pins = self.pins
        assert pins is not None
        start_mm = (pins.position_min_mm + pins.position_max_mm) / 2
        return start_mm + (-1.0 if pins.dir_inverted else 1.0) * steps * pins.step_mm

    def pressed(self, steps: int) -> bool:
        pins = self.pins
        if pins is None:
            return False
        at_mm = self.at_mm(steps)
        return at_mm >= pins.position_endstop_mm if pins.homes_positive else at_mm <= pins.position_endstop_mm

    def endstop_pressed(self, clock: int) -> bool:
        """Whether the carriage is at or past its endstop at ``clock``."""
        return self.pressed(self.steps_at(clock))

    def pressed_from(self, clock: int) -> int | None:
        """The first clock from ``clock`` on at which the endstop is pressed, as far as the queued
        moves go (None: not within them)."""
        if self.endstop_pressed(clock):
            return clock
        steps = self.steps_at(clock)
        for move in self.moves:
            done = move.steps_by(clock)
            if self.pressed(steps + move.direction * (move.count - done)):
                low, high = done + 1, move.count  # the first step that presses it: pressed is monotone in a move
                while low < high:
                    mid = (low + high) // 2
                    if self.pressed(steps + move.direction * (mid - done)):
                        high = mid
                    else:
                        low = mid + 1
                return max(move.step_clock(low), clock)
            steps += move.direction * (move.count - done)
        return None
