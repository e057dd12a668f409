"""Moves as Marlin 2.1 bounds them: software endstops on homed axes, M114's Count, and moves that
cost the clock one step per block, not per tick."""

from __future__ import annotations

import pytest

from protocol.build import build_printer
from protocol.planner import SOFT_MAX_MM, STEPS_PER_MM

HUGE = "1" + "0" * 45  # no exponent: strtof gives +inf (Marlin's value_float stops at 'E' anyway)


def _send(printer, *lines: str) -> list[str]:
    for line in lines:
        printer.receive(line.encode() + b"\n")
    printer.run_until_idle(3600)
    return printer.take_output().decode().splitlines()


@pytest.fixture
def printer():
    p = build_printer(with_bed=False)
    p.take_output()
    return p


def test_m114_count_is_the_planners_steps(printer):
    """report_current_position_projected(): Count is planner.position, steps of the last move queued."""
    assert _send(printer, "G1 X10 Y-2.5 Z0.3 E4", "M114")[-2] == "X:10.00 Y:-2.50 Z:0.30 E:4.00 Count X:800 Y:-200 Z:120"


def test_a_huge_coordinate_on_a_homed_axis_lands_on_the_soft_endstop(printer):
    lines = _send(printer, "G28", f"G1 X{HUGE}", "M114", "M105")
    steps = int(SOFT_MAX_MM["X"] * STEPS_PER_MM["X"])
    assert lines[:3] == ["ok", "ok", f"X:200.00 Y:0.00 Z:0.00 E:0.00 Count X:{steps} Y:0 Z:0"]
    assert lines[-1].startswith("ok T:")  # the move took its few seconds, not 414 days
    assert _send(printer, "G91", f"G1 X-{HUGE}", "M114")[-2].startswith("X:0.00 ")


def test_soft_endstops_clamp_homed_axes_to_the_bed(printer):
    assert _send(printer, "G28", "G1 X500 Y-50 Z900", "M114")[-2] == (
        "X:200.00 Y:0.00 Z:200.00 E:0.00 Count X:16000 Y:0 Z:80000")


def test_only_homed_axes_are_clamped(printer):
    """G28 X homes X alone; Y and Z go where they are told, as Marlin's axis_was_homed() decides."""
    assert _send(printer, "G28 X", "G1 X-5 Y300 Z-1", "M114")[-2] == (
        "X:0.00 Y:300.00 Z:-1.00 E:0.00 Count X:0 Y:24000 Z:-400")


def test_an_unhomed_axis_takes_a_huge_move_as_the_board_does(printer):
    """No soft endstop before homing: inf becomes LONG_MIN steps and the move runs until M410."""
    printer.receive(f"G1 X{HUGE}\n".encode())
    printer.run_for(60)
    assert printer.planner.blocks
    printer.receive(b"M410\n")
    assert _send(printer, "M105")[-1].startswith("ok T:")


def test_m400_runs_the_clock_a_block_at_a_time(printer):
    """M400 behind 180 s of Z moves: the clock advances to each block's end (so a host at --speed
    max gets its ok at once), not one tick per loop."""
    calls = []
    run_ticks = printer.twin.run_ticks
    printer.twin.run_ticks = lambda n: (calls.append(n), run_ticks(n))[1]
    start_s = printer.time_s
    lines = _send(printer, "G1 Z900", "M400")
    assert lines[0] == lines[-1] == "ok" and set(lines[1:-1]) == {"echo:busy: processing"}
    assert printer.time_s - start_s == pytest.approx(900 / 5, abs=0.1)  # Z at DEFAULT_MAX_FEEDRATE 5 mm/s
    assert len(calls) < 300  # a wake per keepalive (2 s) and per block; 175,781 ticks, a call each, before
