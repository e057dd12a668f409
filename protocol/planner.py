"""A motion planner without axes: moves take time and feed filament, nothing else.

The twin has no steppers, but G-code files are mostly moves, and an extrusion move is the
disturbance a hotend feels: filament at room temperature entering the melt zone at a feed rate.
Each G0/G1 becomes a block lasting its distance over its feed rate (Marlin's feed rate applies
to the XYZ distance, or to E alone for an E-only move), feeding ``E / duration`` mm/s of filament.
Blocks run one after the other while the clock runs; like Marlin's planner the buffer holds
BLOCK_BUFFER_SIZE blocks, and a host streaming moves waits for a free slot.

Marlin's widths and limits bound what a block can be (module/planner.cpp, _populate_block, with
the stock Configuration.h): the planner's positions are int32 steps (``LROUND(mm x steps/mm)``,
and avr-libc's lround gives LONG_MIN for a value that is not finite or overflows), the distance
comes from the step deltas, each axis keeps to its DEFAULT_MAX_FEEDRATE, a block never steps
slower than MINIMAL_STEP_RATE, and an extrusion longer than EXTRUDE_MAXLENGTH is dropped
(PREVENT_LENGTHY_EXTRUDE). So every block lasts a finite time: at most 2^32 steps at 120 steps/s.

Software endstops (MIN/MAX_SOFTWARE_ENDSTOPS, on in the stock Configuration.h) clamp a move's
destination on every axis that was homed (module/motion.cpp apply_motion_limits): X and Y to
0..X_BED_SIZE/Y_BED_SIZE (200 mm), Z to Z_MIN_POS..Z_MAX_POS (0..200 mm). A number too large for
a float (``G1 X1`` followed by 46 zeros) parses as +inf (strtof) and is clamped to the limit; on an
axis never homed it is not, as on the board, and the move runs for the 2^32 steps it became.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from firmware_port.fixed import INT32_MAX, INT32_MIN, wrap_s32
from firmware_port.marlin.constants import TEMP_TIMER_FREQUENCY
from protocol.gcode import float32
from twin.clock import TICK_S

BLOCK_BUFFER_SIZE = 16  # Marlin Configuration_adv.h (AVR default)
DEFAULT_FEEDRATE_MM_S = 25.0  # until the first F word (Marlin starts at 1500 mm/min)
AXES = "XYZE"
STEPS_PER_MM = {"X": 80.0, "Y": 80.0, "Z": 400.0, "E": 500.0}  # DEFAULT_AXIS_STEPS_PER_UNIT
MAX_FEEDRATE_MM_S = {"X": 300.0, "Y": 300.0, "Z": 5.0, "E": 25.0}  # DEFAULT_MAX_FEEDRATE
MINIMAL_STEP_RATE = 120  # planner.h: the slowest a block steps, steps/s
EXTRUDE_MAXLENGTH_MM = 200  # Configuration.h, PREVENT_LENGTHY_EXTRUDE
HOMED_AXES = "XYZ"
SOFT_MIN_MM = {"X": 0.0, "Y": 0.0, "Z": 0.0}  # Configuration.h X_MIN_POS, Y_MIN_POS, Z_MIN_POS
SOFT_MAX_MM = {"X": 200.0, "Y": 200.0, "Z": 200.0}  # X_MAX_POS = X_BED_SIZE, Y_MAX_POS = Y_BED_SIZE, Z_MAX_POS
STR_ERR_LONG_EXTRUDE_STOP = "echo: too long extrusion prevented\n"  # language.h, via SERIAL_ECHO_MSG
CLEANING_S = TEMP_TIMER_FREQUENCY * TICK_S  # quick_stop(): cleaning_buffer_counter, counted down by the temperature ISR


def lround32(x: float) -> int:
    """avr-libc ``lround`` into a 32-bit long: half away from zero; LONG_MIN when x is not finite
    or does not fit (the avr-libc manual's stated result)."""
    if not math.isfinite(x):
        return INT32_MIN
    n = math.floor(abs(x) + 0.5)
    n = n if x >= 0 else -n
    return n if INT32_MIN <= n <= INT32_MAX else INT32_MIN


@dataclass
class Block:
    duration_s: float
    flow_mm_s: float  # filament feed during the block (negative: retraction)
    start_steps: dict[str, int]  # the steppers' position (int32 counts) when the block begins
    delta_steps: dict[str, int]  # what the block steps on each axis
    step_events: int  # the largest of those: the block's step event count

    def stepped(self, fraction: float) -> dict[str, int]:
        """Where the steppers are after ``fraction`` of the block's time: each axis's Bresenham
        count after that share of the step events (the stepper ISR's delta_error, starting at
        -step_event_count and adding 2 x steps per event, steps on reaching 0)."""
        events = min(self.step_events, math.floor(fraction * self.step_events))
        position = {}
        for axis, delta in self.delta_steps.items():
            steps = (2 * events * abs(delta) + self.step_events) // (2 * self.step_events)
            position[axis] = wrap_s32(self.start_steps[axis] + (steps if delta >= 0 else -steps))
        return position


class Planner:
    """Positions, modes and the queue of blocks; the printer runs them on its clock."""

    def __init__(self) -> None:
        self.position = {axis: 0.0 for axis in AXES}  # current_position, float32 mm
        self.steps = {axis: 0 for axis in AXES}  # planner.position, int32 steps
        self.absolute_xyz = True  # G90 / G91
        self.absolute_e = True  # M82 / M83
        self.feedrate_mm_s = DEFAULT_FEEDRATE_MM_S
        self.blocks: deque[Block] = deque()
        self.block_left_s = 0.0  # time left in the block at the head of the queue
        self.homed: set[str] = set()  # axis_homed: axes G28 homed since the reset
        self.soft_endstops = True  # soft_endstop._enabled
        self.stepper_end = dict(self.steps)  # the steppers' position once every queued block has run
        self.cleaning_s = 0.0  # left of quick_stop()'s cleaning window

    def __repr__(self) -> str:
        return f"Planner({len(self.blocks)} blocks, position {self.position})"

    @property
    def busy(self) -> bool:
        """Planner::busy(): blocks queued or the cleaning window still open (what synchronize() waits for)."""
        return bool(self.blocks) or self.cleaning_s > 0

    @property
    def full(self) -> bool:
        return len(self.blocks) >= BLOCK_BUFFER_SIZE

    @property
    def flow_mm_s(self) -> float:
        """Filament feed now: the head block's."""
        return self.blocks[0].flow_mm_s if self.blocks else 0.0

    def move(self, params: dict[str, float]) -> str:
        """G0/G1 with numeric parameters X Y Z E F: queue a block (the caller checks ``full``).

        Returns what Marlin prints about it ('' or the too-long-extrusion message).
        """
        if "F" in params and params["F"] > 0:
            self.feedrate_mm_s = float32(params["F"] / 60.0)
        for axis in AXES:
            if axis in params:
                absolute = self.absolute_e if axis == "E" else self.absolute_xyz
                self.position[axis] = params[axis] if absolute else float32(self.position[axis] + params[axis])
        self._apply_motion_limits()
        delta_steps = {}
        for axis in AXES:
            target_steps = lround32(self.position[axis] * STEPS_PER_MM[axis])
            delta_steps[axis] = wrap_s32(target_steps - self.steps[axis])
            self.steps[axis] = target_steps
        message = ""
        if abs(delta_steps["E"]) > STEPS_PER_MM["E"] * EXTRUDE_MAXLENGTH_MM:
            delta_steps["E"] = 0  # "behave as if the move really took place, but ignore E"
            message = STR_ERR_LONG_EXTRUDE_STOP
        self._queue(delta_steps)
        return message

    def _queue(self, delta_steps: dict[str, int]) -> None:
        step_events = max(abs(d) for d in delta_steps.values())
        if step_events == 0:
            return
        mm = {axis: delta_steps[axis] / STEPS_PER_MM[axis] for axis in AXES}
        xyz = math.sqrt(sum(mm[a] ** 2 for a in "XYZ"))
        distance = xyz if xyz > 0 else abs(mm["E"])
        duration_s = distance / self.feedrate_mm_s
        for axis in AXES:  # limit_and_warn / the speed factor: no axis beyond its maximum
            duration_s = max(duration_s, abs(mm[axis]) / MAX_FEEDRATE_MM_S[axis])
        duration_s = min(duration_s, step_events / MINIMAL_STEP_RATE)
        start = self.stepper_end
        self.stepper_end = {axis: wrap_s32(start[axis] + delta_steps[axis]) for axis in AXES}
        self.blocks.append(Block(duration_s, mm["E"] / duration_s, start, delta_steps, step_events))
        if len(self.blocks) == 1:
            self.block_left_s = duration_s

    def _apply_motion_limits(self) -> None:
        """apply_motion_limits(): each homed axis into its soft endstops, NOLESS then NOMORE
        (``if (min > v) v = min``), so +-inf lands on a limit and NaN passes as on the board."""
        if not self.soft_endstops:
            return
        for axis in self.homed:
            value = self.position[axis]
            if SOFT_MIN_MM[axis] > value:
                value = SOFT_MIN_MM[axis]
            if SOFT_MAX_MM[axis] < value:
                value = SOFT_MAX_MM[axis]
            self.position[axis] = value

    def home(self, axes: str) -> None:
        """G28: the given axes (all of X, Y, Z when none is given) are at 0 and count as homed."""
        homing = [axis for axis in HOMED_AXES if axis in axes] or list(HOMED_AXES)
        self.set_position({axis: 0.0 for axis in homing})
        self.homed.update(homing)

    def set_position(self, params: dict[str, float]) -> None:
        """G92: the given axes take the given values (all zero when none is given)."""
        for axis in AXES:
            if axis in params or not params:
                self.position[axis] = params.get(axis, 0.0)
                self.steps[axis] = lround32(self.position[axis] * STEPS_PER_MM[axis])
        self.stepper_end = dict(self.steps)  # the steppers take it when the blocks before it have run

    def ticks_to_next_change(self) -> int | None:
        """Clock ticks until the head block ends (the flow may change then) or the cleaning window
        closes, at least 1; None when the planner is not busy."""
        if self.blocks:
            return max(1, round(self.block_left_s / TICK_S))
        return max(1, round(self.cleaning_s / TICK_S)) if self.cleaning_s else None

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of motion pass (the printer never crosses a block boundary within)."""
        self.cleaning_s = max(0.0, self.cleaning_s - seconds)
        if self.cleaning_s <= 1e-12:
            self.cleaning_s = 0.0
        while self.blocks and seconds > 0:
            step = min(seconds, self.block_left_s)
            self.block_left_s -= step
            seconds -= step
            if self.block_left_s <= 1e-12:
                self.blocks.popleft()
                self.block_left_s = self.blocks[0].duration_s if self.blocks else 0.0

    def clear(self) -> None:
        """Kill (M112): the queue is gone."""
        self.blocks.clear()
        self.block_left_s = 0.0

    def quickstop(self) -> None:
        """quickstop_stepper() (M410): the blocks are dropped, the steppers stop where they are,
        and the position becomes theirs (set_current_from_steppers_for_axis(ALL_AXES_ENUM): steps
        times the float mm_per_step; sync_plan_position()). The cleaning window opens."""
        if self.blocks:
            head = self.blocks[0]
            self.stepper_end = head.stepped(1.0 - self.block_left_s / head.duration_s)
        self.clear()
        self.steps = dict(self.stepper_end)
        self.position = {axis: float32(float32(self.steps[axis]) * float32(1.0 / STEPS_PER_MM[axis])) for axis in AXES}
        self.cleaning_s = CLEANING_S
