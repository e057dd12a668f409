"""The clock that keeps running: idle speed, free-running commands, wall-paced reports."""

from __future__ import annotations

import re
import time

import pytest
import serial

import protocol  # noqa: F401  registers twin://
from firmware_port.thermistor import TEMP_ONE
from protocol.build import build_printer
from protocol.pacing import MAX, Pacer, parse_idle_speed
from tests.helpers.serial_host import expect, twin_serial

REPORT = re.compile(r"^ T:(\d+\.\d\d) /200\.00")
LIVENESS_S = 600  # a bound on waiting, not a timing: the machine may be loaded


class FakeWall:
    """A wall clock the test moves."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def drive(pacer: Pacer, wall: FakeWall, wall_s: float, step_s: float = 0.05) -> None:
    """Let ``wall_s`` of fake wall time pass, the transport calling advance() as it would."""
    end_s = wall.now_s + wall_s
    while wall.now_s < end_s:
        wall.now_s += step_s
        while pacer.advance() == 0.0:
            pass


def test_an_idle_printer_heats_at_the_idle_speed():
    printer = build_printer(with_bed=False)
    wall = FakeWall()
    pacer = Pacer(printer, MAX, idle_speed=10, clock=wall)
    printer.receive(b"M104 S200\n")
    start_c = printer.twin.board.hotend.temp_q5 / TEMP_ONE
    drive(pacer, wall, 3.0)
    assert printer.time_s == pytest.approx(30.0, abs=0.6)  # 10 x 3 s, within one 0.05 s wall step
    assert printer.twin.board.hotend.temp_q5 / TEMP_ONE > start_c + 20


def test_m155_reports_follow_the_wall_clock_when_the_clock_runs_fast():
    printer = build_printer(with_bed=False)
    wall = FakeWall()
    pacer = Pacer(printer, MAX, idle_speed=50, clock=wall)
    printer.receive(b"M155 S1\n")
    printer.take_output()
    drive(pacer, wall, 10.0)
    reports = [line for line in printer.take_output().decode().splitlines() if line.startswith(" T:")]
    assert 9 <= len(reports) <= 11  # one per wall second, not 50 (one per virtual second)


def test_busy_keepalives_follow_the_wall_clock_during_a_free_run():
    printer = build_printer(with_bed=False)
    wall = FakeWall()
    pacer = Pacer(printer, MAX, clock=wall)
    printer.receive(b"G4 S600\n")
    drive(pacer, wall, 1.0)  # ten minutes of dwell run free within a wall second
    lines = printer.take_output().decode().splitlines()
    assert lines[-1] == "ok" and printer.time_s > 600
    assert lines.count("echo:busy: processing") <= 1  # host-driven, it would be 300


def test_the_host_driven_clock_stops_while_idle():
    printer = build_printer(with_bed=False)
    wall = FakeWall()
    pacer = Pacer(printer, MAX, idle_speed=0, clock=wall)
    printer.receive(b"M104 S200\n")
    start_s = printer.time_s
    drive(pacer, wall, 5.0)
    assert printer.time_s == start_s


def test_parse_idle_speed():
    assert parse_idle_speed("0") == 0 and parse_idle_speed("2.5") == 2.5
    for bad in ("-1", "nan", "inf", "fast", ""):
        with pytest.raises(ValueError, match="idle speed"):
            parse_idle_speed(bad)


@pytest.mark.slow


def test_default_twin_serial_heats_and_reports_while_the_host_only_reads(tmp_path):
    """A host that sets M155 S1 and M104 S200, then only reading."""
    with twin_serial(tmp_path=tmp_path) as (_, path):
        with serial.Serial(path, 250000, timeout=1) as port:
            expect(port, "M304", timeout_s=LIVENESS_S)  # the end of the banner
            port.write(b"M155 S1\nM104 S200\n")
            temps_c: list[float] = []
            deadline = time.monotonic() + LIVENESS_S
            while len(temps_c) < 5 and time.monotonic() < deadline:
                line = port.readline().decode("latin-1")
                if m := REPORT.match(line):
                    temps_c.append(float(m.group(1)))
            assert len(temps_c) == 5, f"auto-reports: {temps_c}"
            assert temps_c[-1] > temps_c[0] + 1  # heating while the host only reads
            port.write(b"M155 S0\nM109 S200\n")
            expect(port, r"^ok$", timeout_s=LIVENESS_S)  # M155's (M104's came with the reports)
            lines = expect(port, r"^ok$", timeout_s=LIVENESS_S)  # M109's, after its W: countdown
            assert any(line.endswith("W:0") for line in lines)
            port.write(b"M303 E0 S200 C3\n")
            assert "PID Autotune finished" in "\n".join(expect(port, r"^ok$", timeout_s=LIVENESS_S))
