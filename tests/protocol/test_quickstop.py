"""M410 as Marlin 2.1's quickstop_stepper() runs it: when the line is read and again when it runs,
the blocks are dropped, the position is where the steppers stopped, and planner.synchronize()
waits out quick_stop()'s cleaning window (cleaning_buffer_counter, TEMP_TIMER_FREQUENCY
temperature-ISR ticks). A command waiting on the moves then goes on."""

from __future__ import annotations

import re

import pytest

from firmware_port.marlin.constants import TEMP_TIMER_FREQUENCY
from protocol.build import build_printer
from protocol.planner import STEPS_PER_MM
from twin.clock import TICK_S

POSITION = re.compile(r"X:(-?\d+\.\d\d) Y:\S+ Z:\S+ E:(-?\d+\.\d\d) Count X:(-?\d+) Y:\S+ Z:\S+")


@pytest.fixture
def printer():
    p = build_printer(with_bed=False)
    p.take_output()
    return p


def _receive(printer, *lines: str) -> None:
    for line in lines:
        printer.receive(line.encode() + b"\n")


def _output(printer) -> list[str]:
    return printer.take_output().decode().splitlines()


@pytest.mark.parametrize("wait", ["M400", "G4 P10", "G1 X20"])
def test_m410_ends_a_wait_behind_an_absurd_move(printer, wait):
    """G92 far off on a homed axis, then a move back onto the bed: 2^31 steps at 120 steps/s
    (six centuries). Whatever waits on it (M400, G4's synchronize, a G1 behind a full planner)
    goes on after M410, and the printer answers again."""
    _receive(printer, "G28", "G92 X-1000000000", "G1 X10")
    if wait.startswith("G1"):
        _receive(printer, *[f"G1 X{x}" for x in range(11, 26)])  # the planner's other 15 blocks: G1 X20 waits
    _receive(printer, wait)
    printer.run_while_busy(5)
    assert printer.executing and printer.planner.blocks
    before = _output(printer)
    _receive(printer, "M410")
    printer.run_while_busy(10)
    after = _output(printer)
    assert not printer.executing and not printer.planner.busy
    assert (before + after).count("ok") == before.count("ok") + 2  # the wait's ok, then M410's
    printer.receive(b"M105\n")
    printer.run_while_busy(1)
    assert _output(printer)[-1].startswith("ok T:")


def test_the_position_is_where_the_steppers_stopped(printer):
    """set_current_from_steppers_for_axis(ALL_AXES_ENUM): not the destination, the steppers' count
    (M114's Count is planner.position, synced to it); the next move starts from there."""
    _receive(printer, "G28", "G1 X200 E20 F300")  # 40 s at 5 mm/s, feeding 0.5 mm/s
    printer.run_for(10)
    _output(printer)
    start_s = printer.time_s
    _receive(printer, "M410")
    printer.run_while_busy(5)
    assert _output(printer) == ["ok"]
    assert printer.time_s - start_s == pytest.approx(TEMP_TIMER_FREQUENCY * TICK_S, abs=2 * TICK_S)
    _receive(printer, "M114")
    printer.run_while_busy(1)
    x, e, count = POSITION.match(_output(printer)[0]).groups()
    assert 49 < float(x) < 51 and 4.9 < float(e) < 5.1
    assert int(count) == round(float(x) * STEPS_PER_MM["X"])
    _receive(printer, "G1 X100", "M400", "M114")
    printer.run_until_idle()
    assert _output(printer)[-2].startswith(f"X:100.00 Y:0.00 Z:0.00 E:{e} Count X:8000 ")  # E stays where it stopped
