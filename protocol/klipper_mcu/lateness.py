"""What the twin MCU's lenient mode forgave: late events and missed deadlines, counted and worded for
its stats line and stderr (mcu.py; motion.py's homing timeouts count here too)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Lateness:
    """Lenient mode's forgiven timing faults since the MCU started (``reported``: as last logged)."""

    clock_freq: int  # the MCU's clocks per second
    late_events: int = 0  # events the host scheduled in the past
    max_late_clocks: int = 0  # the latest of them
    forgiven_deadlines: int = 0  # missed max_duration deadlines whose next event came within the grace
    max_overdue_clocks: int = 0  # the longest a pin stayed at its default before that event came
    reported: tuple[int, int] = (0, 0)

    def line(self) -> str:
        ms = 1000 / self.clock_freq
        return (f"lenient timing: {self.late_events} late events (up to {self.max_late_clocks * ms:.1f} ms late), "
                f"{self.forgiven_deadlines} max_duration misses forgiven (up to {self.max_overdue_clocks * ms:.1f} ms "
                "after it); MCU clock")

    def changed(self) -> bool:
        """True once per change of the counts (the stats timer logs the line then)."""
        now = (self.late_events, self.forgiven_deadlines)
        if now == self.reported:
            return False
        self.reported = now
        return True
