"""What a run records: one row per firmware reading (every 0.16384 s), plus timed events.

Columns (units in the names): time, per heater the target, the firmware's measured
temperature, the true block and sensor-node temperatures and the heater duty (soft-PWM
amount / 127), and the part fan. Events are what the firmware printed (protection trips,
autotune lines) and what the scenario did, with their times. Exports: CSV, and Klipper's
``Stats`` log lines once per second so existing log tools (graphstats.py) read a twin run.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field

import numpy as np

HEATERS = ("hotend", "bed")
KLIPPER_NAMES = {"hotend": "extruder", "bed": "heater_bed"}
TRIP_SUFFIX = ", system stopped! Heater_ID: "  # Marlin's _temp_error line
COLUMNS = ("t_s",) + tuple(
    f"{h}_{c}" for h in HEATERS for c in ("target_c", "measured_c", "block_c", "sensor_c", "duty")
) + ("fan",)


@dataclass
class Trace:
    """Rows appended by the engine; ``column(name)`` gives a numpy array."""

    rows: list[tuple] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)  # (t_s, text)

    def append(self, row: tuple) -> None:
        self.rows.append(row)

    def add_event(self, t_s: float, text: str) -> None:
        self.events.append((t_s, text))

    def protection_trips(self) -> list[tuple[float, str, str]]:
        """(time, what, heater id) of each thermal protection error Marlin printed."""
        found = []
        for t_s, text in self.events:
            if text.startswith("Error:") and TRIP_SUFFIX in text:
                what, heater_id = text[len("Error:") :].split(TRIP_SUFFIX)
                found.append((t_s, what, heater_id))
        return found

    def column(self, name: str) -> np.ndarray:
        index = COLUMNS.index(name)
        return np.array([row[index] for row in self.rows], dtype=float)

    def to_csv(self) -> str:
        """All rows, then one commented line per event (``# event <t_s> <text>``)."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(COLUMNS)
        for row in self.rows:
            writer.writerow(f"{v:.4f}" if isinstance(v, float) else v for v in row)
        for t_s, text in self.events:
            out.write(f"# event {t_s:.3f} {text}\n")
        return out.getvalue()

    def to_klipper_stats(self, heaters: tuple[str, ...] = HEATERS) -> str:
        """One ``Stats`` line per second, as klippy.log writes them (graphstats.py reads these).

        temp is the last reading, pwm the duty in force, target rounded to an integer.
        """
        lines = []
        next_s = 1.0
        for row in self.rows:
            t_s = row[0]
            if t_s < next_s:
                continue
            values = dict(zip(COLUMNS, row))
            parts = [f"Stats {t_s:.1f}:"]
            for h in heaters:
                parts.append(
                    f"{KLIPPER_NAMES[h]}: target={values[h + '_target_c']:.0f} "
                    f"temp={values[h + '_measured_c']:.1f} pwm={values[h + '_duty']:.3f}"
                )
            parts.append(f"print_time={t_s:.3f} buffer_time=0.000 print_stall=0")
            lines.append(" ".join(parts))
            next_s = np.floor(t_s) + 1.0
        return "\n".join(lines) + ("\n" if lines else "")
