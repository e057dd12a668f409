"""The one virtual clock: integer ISR ticks, their conversion to seconds, and the event queue.

A tick is one temperature ISR of the ATmega328 (Timer0 compare, 1.024 ms; Marlin's
temperature.cpp runs it at 976.5625 Hz). Every engine (``Twin``, ``BatchTwin``, ``KlipperTwin``)
keeps its scheduled actions in an ``EventQueue``: due in time order, ties broken by priority and
then by the order they were pushed, so a run is the same bit for bit every time.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from firmware_port.marlin.constants import ISR_PERIOD_S

TICK_S = float(ISR_PERIOD_S)  # 1.024 ms


def ticks_at(t_s: float) -> int:
    """The first tick at or after ``t_s`` seconds."""
    return int(np.ceil(round(t_s / TICK_S, 9)))


def tick_near(t_s: float) -> int:
    """The tick nearest to ``t_s`` seconds."""
    return round(t_s / TICK_S)


def seconds(ticks: int) -> float:
    return ticks * TICK_S


class EventQueue:
    """Actions due at a time (ticks or seconds: any ordered number), in a deterministic order."""

    def __init__(self) -> None:
        self._heap: list[tuple[Any, int, int, Callable, tuple]] = []
        self._seq = itertools.count()

    def __len__(self) -> int:
        return len(self._heap)

    def __repr__(self) -> str:
        return f"EventQueue({len(self)} due, next at {self.next_at()})"

    def push(self, at: Any, action: Callable, *args: Any, priority: int = 0) -> None:
        """Run ``action(*args)`` at ``at``; among equal times the lower priority runs first."""
        heapq.heappush(self._heap, (at, priority, next(self._seq), action, args))

    def next_at(self) -> Any | None:
        """When the earliest action is due (None when the queue is empty)."""
        return self._heap[0][0] if self._heap else None

    def pop_due(self, now: Any) -> Iterator[tuple[Any, Callable, tuple]]:
        """Pop the actions due at or before ``now``, earliest first (including ones pushed while
        iterating, if they are due)."""
        while self._heap and self._heap[0][0] <= now:
            at, _, _, action, args = heapq.heappop(self._heap)
            yield at, action, args
