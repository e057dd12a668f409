"""What a run records: one row per firmware reading (every 0.16384 s), plus timed events.

A row is time, then per heater (hotend, bed) the target, the firmware's measured temperature,
the true block and sensor-node temperatures and the heater duty (soft-PWM amount / 127), then
the part fan. Events are what the firmware printed (protection trips, autotune lines) and what
the scenario did. ``result()`` turns the recording into the public ``RunResult`` (exports and
plots live there).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from twin.result import FIELDS, HEATERS, RunResult


@dataclass
class Trace:
    """Rows appended by the engine, in the layout of ``HEATERS`` x ``FIELDS`` after the time."""

    rows: list[tuple] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)  # (t_s, text)
    signals: dict[str, dict[str, list[float]]] = field(default_factory=dict)  # heater -> name -> one value per row

    def add_signals(self, heater: str, values: dict[str, float]) -> None:
        """A controller's published internals for the row just appended."""
        own = self.signals.setdefault(heater, {})
        for name, value in values.items():
            own.setdefault(name, []).append(value)

    def append(self, row: tuple) -> None:
        self.rows.append(row)

    def add_event(self, t_s: float, text: str) -> None:
        self.events.append((t_s, text))

    def result(self, heaters: Sequence[str] = HEATERS, label: str = "") -> RunResult:
        """The recording as a RunResult with the named heaters (a board without a bed: hotend only)."""
        width = 1 + len(HEATERS) * len(FIELDS) + 1
        table = np.array(self.rows, dtype=float).reshape(-1, width)
        columns: dict[str, dict] = {}
        for index, name in enumerate(HEATERS):
            if name in heaters:
                first = 1 + index * len(FIELDS)
                columns[name] = {f: table[:, first + k] for k, f in enumerate(FIELDS)}
                own = {k: v for k, v in self.signals.get(name, {}).items() if len(v) == len(table)}
                if own:
                    columns[name]["signals"] = own
        return RunResult.from_columns(table[:, 0], columns, table[:, -1], list(self.events), label)
