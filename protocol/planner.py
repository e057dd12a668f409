"""A motion planner without axes: moves take time and feed filament, nothing else.

The twin has no steppers, but G-code files are mostly moves, and an extrusion move is the
disturbance a hotend feels: filament at room temperature entering the melt zone at a feed rate.
Each G0/G1 becomes a block lasting its distance over its feed rate (Marlin's feed rate applies
to the XYZ distance, or to E alone for an E-only move), feeding ``E / duration`` mm/s of filament.
Blocks run one after the other while the clock runs; like Marlin's planner the buffer holds
BLOCK_BUFFER_SIZE blocks, and a host streaming moves waits for a free slot.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

BLOCK_BUFFER_SIZE = 16  # Marlin Configuration_adv.h (AVR default)
DEFAULT_FEEDRATE_MM_S = 25.0  # until the first F word (Marlin starts at 1500 mm/min)
MIN_FEEDRATE_MM_S = 0.001


@dataclass
class Block:
    duration_s: float
    flow_mm_s: float  # filament feed during the block (negative: retraction)


class Planner:
    """Positions, modes and the queue of blocks; the printer runs them on its clock."""

    def __init__(self) -> None:
        self.position = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        self.absolute_xyz = True  # G90 / G91
        self.absolute_e = True  # M82 / M83
        self.feedrate_mm_s = DEFAULT_FEEDRATE_MM_S
        self.blocks: deque[Block] = deque()
        self.block_left_s = 0.0  # time left in the block at the head of the queue

    @property
    def full(self) -> bool:
        return len(self.blocks) >= BLOCK_BUFFER_SIZE

    @property
    def flow_mm_s(self) -> float:
        """Filament feed now: the head block's."""
        return self.blocks[0].flow_mm_s if self.blocks else 0.0

    def move(self, params: dict[str, float]) -> None:
        """G0/G1 with numeric parameters X Y Z E F: queue a block (the caller checks ``full``)."""
        if "F" in params and params["F"] > 0:
            self.feedrate_mm_s = params["F"] / 60.0
        delta = {}
        for axis in "XYZE":
            if axis in params:
                absolute = self.absolute_e if axis == "E" else self.absolute_xyz
                target = params[axis] if absolute else self.position[axis] + params[axis]
                delta[axis] = target - self.position[axis]
                self.position[axis] = target
        xyz = math.sqrt(sum(delta.get(a, 0.0) ** 2 for a in "XYZ"))
        e = delta.get("E", 0.0)
        distance = xyz if xyz > 0 else abs(e)
        if distance == 0:
            return
        duration_s = distance / max(self.feedrate_mm_s, MIN_FEEDRATE_MM_S)
        self.blocks.append(Block(duration_s, e / duration_s))
        if len(self.blocks) == 1:
            self.block_left_s = duration_s

    def set_position(self, params: dict[str, float]) -> None:
        """G92: the given axes take the given values (all zero when none is given)."""
        for axis in "XYZE":
            if axis in params or not params:
                self.position[axis] = params.get(axis, 0.0)

    def time_to_next_change_s(self) -> float | None:
        """Until the head block ends (the flow may change then), or None when idle."""
        return self.block_left_s if self.blocks else None

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of motion pass (the printer never crosses a block boundary within)."""
        while self.blocks and seconds > 0:
            step = min(seconds, self.block_left_s)
            self.block_left_s -= step
            seconds -= step
            if self.block_left_s <= 1e-12:
                self.blocks.popleft()
                self.block_left_s = self.blocks[0].duration_s if self.blocks else 0.0

    def clear(self) -> None:
        """Kill or reset: the queue is gone."""
        self.blocks.clear()
        self.block_left_s = 0.0
