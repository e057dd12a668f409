"""What a G-code handler sees of the printer: the state and services protocol/commands.py uses.

The handlers act on a ``PrinterContext``; ``protocol.printer.VirtualPrinter`` is one. Declaring the
interface here keeps the import graph one-way: the printer imports the handlers, the handlers
import only this protocol.
"""

from __future__ import annotations

from typing import Protocol

from protocol.lines import LineReader
from protocol.planner import Planner
from protocol.settings import Eeprom
from twin.engine import Twin


class PrinterContext(Protocol):
    """The printer a handler runs on: its twin, its wire, its planner, its host-protocol state."""

    twin: Twin
    planner: Planner
    reader: LineReader
    eeprom: Eeprom
    wait_for_heatup: bool  # M109/M190 wait; M108 clears it
    idle_calls: bool  # False while a command's loop skips idle() (M303)
    keepalive_s: int  # M113
    autoreport_s: int  # M155
    autoreport_tick: int
    autoreport_wall_s: float

    def write(self, text: str) -> None:
        """Serial TX."""

    @property
    def now_tick(self) -> int:
        """The twin's tick now."""

    def after_ms(self, ms: int) -> int:
        """The tick at which the board's millis() will have advanced by ``ms``."""

    def next_reading_tick(self) -> int:
        """The tick of the board's next main-loop action."""

    def wall_s(self) -> float:
        """The transport's wall clock (0 when host-driven)."""
