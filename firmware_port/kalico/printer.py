"""What Kalico's calibration commands ask of the printer around the heater: klippy's ``printer.wait_while``
on the reactor's clock, the G-code console, the M105 line and the part fan. An engine (the Klipper twin)
provides it; the commands stay free of any engine."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol


class Printer(Protocol):
    """The printer a Kalico command runs on."""

    def monotonic(self) -> float:
        """The reactor's time (s)."""
        ...

    def wait_while(self, condition: Callable[[float], bool], interval_s: float = 1.0) -> None:
        """printer.wait_while: condition(eventtime) now and every interval_s after until it is False;
        CommandError("Command interrupted") if the printer shuts down meanwhile."""
        ...

    def respond_info(self, text: str) -> None:
        """gcode.respond_info: each line of text to the host as "// <line>"."""
        ...

    def respond_raw(self, text: str) -> None: ...

    def m105(self, eventtime: float) -> str:
        """The M105 line ("T0:<smoothed> /<target> ...") at eventtime."""
        ...

    def set_part_fan(self, heater_name: str, speed: float) -> None:
        """The part fan (the cooling_fan of the heater's MPC section) at speed 0..1, now."""
        ...


class BusyHeater(Protocol):
    def check_busy(self, eventtime: float) -> bool: ...


def wait_for_temperature(printer: Printer, heater: BusyHeater) -> None:
    """M109's wait (heaters.py _wait_for_temperature): the M105 line every second while the heater is busy."""

    def busy(eventtime: float) -> bool:
        printer.respond_raw(printer.m105(eventtime))
        return heater.check_busy(eventtime)

    printer.wait_while(busy)
