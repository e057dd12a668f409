"""Transports: twin-serial on a pty and on TCP, driven by pyserial as a host would; the twin://
URL handler; pacing; the transcript; CLI errors. Every read has a timeout and every process,
port and socket is closed, so a failure cannot hang the run.
"""

from __future__ import annotations

import ast
import os
import re
import signal
import socket
import subprocess
import time

import pytest
import serial

import protocol  # noqa: F401  registers twin://
from firmware_port.marlin.constants import TEMP_HYSTERESIS_C
from protocol.build import build_printer
from protocol.pacing import CATCH_UP_S, MAX, PACE_S, Pacer, parse_speed
from tests.helpers.serial_host import CLI, READ_TIMEOUT_S, ROOT, START_TIMEOUT_S, expect, twin_serial

SPEED_TOLERANCE_S = 0.1  # virtual: the clock runs in whole timer ticks (about 1 ms)
M105_REPLY = re.compile(r"^ok T:\d+\.\d\d /0\.00 B:\d+\.\d\d /0\.00 @:0 B@:0$")


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, cwd=ROOT, timeout=START_TIMEOUT_S)


# -- a pty, as Printrun or OctoPrint would use it -------------------------------------------------
@pytest.fixture(scope="module")
def pty_twin(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("pty")
    link, log = tmp_path / "printer", tmp_path / "transcript.log"
    with twin_serial("--speed", "max", "--link", str(link), "--log", str(log), "--baud", "250000",
                     tmp_path=tmp_path) as (proc, path):
        yield path, link, log


@pytest.mark.slow


def test_pty_answers_m115_and_m105(pty_twin):
    path, _, _ = pty_twin
    with serial.Serial(path, 115200, timeout=READ_TIMEOUT_S) as port:
        expect(port, "^start$")
        expect(port, "M304")  # the banner's last line
        port.write(b"M115\n")
        assert expect(port, "^ok$")[0].startswith("FIRMWARE_NAME:Marlin 2.1")
        port.write(b"M105\n")
        assert M105_REPLY.match(expect(port, "^ok")[-1])


def test_pty_link_points_at_the_port(pty_twin):
    path, link, _ = pty_twin
    assert os.readlink(link) == path
    with serial.Serial(str(link), 250000, timeout=READ_TIMEOUT_S) as port:
        expect(port, "^start$")
        port.write(b"M105\n")
        assert M105_REPLY.match(expect(port, "^ok")[-1])


def test_pty_reopening_resets_the_board(pty_twin):
    path, _, _ = pty_twin
    port = serial.Serial(path, 115200, timeout=READ_TIMEOUT_S)
    try:
        expect(port, "^start$")
        port.write(b"M104 S100\n")
        expect(port, "^ok$")
        port.close()
        port.open()  # at once, as a host's reconnect does: the board resets like on DTR
        assert expect(port, "^start$") == ["start"]
        assert expect(port, "Reset$") == [" External Reset"]
        port.write(b"M105\n")
        assert M105_REPLY.match(expect(port, "^ok")[-1])  # target 0 again: a fresh board
    finally:
        port.close()


def test_transcript_records_both_directions(pty_twin):
    path, _, log = pty_twin
    with serial.Serial(path, 115200, timeout=READ_TIMEOUT_S) as port:
        expect(port, "^start$")
        port.write(b"M105\n")
        expect(port, "^ok")
    deadline = time.monotonic() + READ_TIMEOUT_S  # the server writes it after sending the reply
    while b"ok T:" not in log.read_bytes() and time.monotonic() < deadline:
        time.sleep(0.02)
    lines = log.read_text().splitlines()
    assert lines[0].startswith("# heater-twin transcript")
    records = [line.split(" ", 3) for line in lines[1:]]
    for direction, virtual_s, wall_s, _ in records:
        assert direction in "<>*" and float(virtual_s) >= 0 and float(wall_s) >= 0
    data = {d: [ast.literal_eval(r[3]) for r in records if r[0] == d] for d in "<>*"}
    assert b"M105\n" in data[">"]
    assert any(chunk.startswith(b"ok T:") for chunk in data["<"])
    assert data["*"][:2] == ["host connected", "board reset"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.slow
def test_signal_stops_cleanly_and_removes_the_link(tmp_path, signum):
    link = tmp_path / "printer"
    with twin_serial("--link", str(link), tmp_path=tmp_path) as (proc, path):
        assert os.readlink(link) == path
        proc.send_signal(signum)
        assert proc.wait(timeout=START_TIMEOUT_S) == 0
    assert not os.path.lexists(link)
    assert "Traceback" not in (tmp_path / "stderr.txt").read_text()


# -- TCP, as pyserial's socket:// and Pronterface's host:port use it ---------------------------------
@pytest.mark.slow
def test_tcp_serves_and_each_connection_resets(tmp_path):
    with twin_serial("--tcp", "127.0.0.1:0", tmp_path=tmp_path) as (_, address):
        assert re.fullmatch(r"127\.0\.0\.1:\d+", address)
        for _ in range(2):
            with serial.serial_for_url(f"socket://{address}", timeout=READ_TIMEOUT_S) as port:
                expect(port, "^start$")
                port.write(b"M105\n")
                assert M105_REPLY.match(expect(port, "^ok")[-1])


# -- twin://, in process -----------------------------------------------------------------------------
def test_url_handler_answers_m105():
    with serial.serial_for_url("twin://?firmware=pid&speed=max", timeout=READ_TIMEOUT_S) as port:
        assert expect(port, "^start$") == ["start"]
        port.write(b"M105\n")
        assert M105_REPLY.match(expect(port, "^ok")[-1])


def test_url_handler_m109_at_speed_max_runs_free():
    with serial.serial_for_url("twin://?speed=max", timeout=READ_TIMEOUT_S) as port:
        expect(port, "M304")  # the end of the banner
        port.write(b"M104 S200\n")
        expect(port, "^ok$")
        start_wall, start_virtual = time.monotonic(), port.printer.time_s
        port.write(b"M109 S200\n")
        lines = expect(port, "^ok$")
        wall_s, virtual_s = time.monotonic() - start_wall, port.printer.time_s - start_virtual
    reports = [line for line in lines if line.startswith(" T:")]
    # the last report ends the 10 s residency (W:0), never beyond TEMP_HYSTERESIS (3 C) since
    last = re.match(r" T:(\S+) /200\.00 .* W:0$", reports[-1])
    assert len(reports) > 50 and last and abs(float(last[1]) - 200) <= TEMP_HYSTERESIS_C
    assert 60 < virtual_s < 300  # about 100 s from 25 C, with M109's 10 s residency
    assert wall_s < virtual_s  # it runs free: hundreds of times faster than real time when quiet


def test_url_handler_speed_50_follows_the_wall_clock():
    with serial.serial_for_url("twin://?speed=50", timeout=0.1) as port:
        # each "now" the clock is brought up to lies between the wall times read either side of in_waiting,
        # so the virtual time elapsed is 50 x a wall time between those bounds, however busy the machine
        before_start = time.monotonic()
        port.in_waiting  # noqa: B018  brings the clock up to now
        after_start, start_virtual = time.monotonic(), port.printer.time_s
        time.sleep(0.5)
        before_end = time.monotonic()
        port.in_waiting  # noqa: B018
        after_end, virtual_s = time.monotonic(), port.printer.time_s - start_virtual
    assert 50 * (before_end - after_start) - SPEED_TOLERANCE_S <= virtual_s
    assert virtual_s <= 50 * (after_end - before_start) + SPEED_TOLERANCE_S


def test_url_handler_read_timeout_when_idle():
    with serial.serial_for_url("twin://", timeout=0.2) as port:
        port.read(port.in_waiting)
        start = time.monotonic()
        assert port.read(10) == b""
        assert 0.15 < time.monotonic() - start < 60  # its timeout, not a hang


def test_url_handler_dtr_resets_and_buffers_reset():
    with serial.serial_for_url("twin://", timeout=READ_TIMEOUT_S) as port:
        assert port.in_waiting > 0
        port.reset_input_buffer()
        assert port.in_waiting == 0
        port.dtr = False
        port.dtr = True
        assert expect(port, "Reset$") == ["start", " External Reset"]


def test_url_handler_names_unknown_parameters():
    with pytest.raises(serial.SerialException, match="unknown parameter.*baud, colour"):
        serial.serial_for_url("twin://?firmware=pid&colour=red&baud=9600")
    with pytest.raises(serial.SerialException, match="speed must be"):
        serial.serial_for_url("twin://?speed=fast")


# -- pacing --------------------------------------------------------------------------------------------
def test_parse_speed():
    assert parse_speed("max") == MAX
    assert parse_speed("1") == 1.0 and parse_speed("12.5") == 12.5
    for bad in ("0", "-3", "nan", "inf", "fast", ""):
        with pytest.raises(ValueError, match="speed must be"):
            parse_speed(bad)


def test_pacer_catches_up_in_bounded_steps():
    printer = build_printer(with_bed=False)
    wall = [0.0]
    pacer = Pacer(printer, 20.0, clock=lambda: wall[0])
    wall[0] = 1.0  # one wall second: 20 virtual seconds are due
    steps = 0
    while (wait_s := pacer.advance()) == 0.0:
        steps += 1
    assert wait_s == PACE_S
    assert steps == pytest.approx(1 / CATCH_UP_S, abs=1)
    assert printer.time_s == pytest.approx(20.0, abs=0.01)


def test_pacer_host_driven_at_max_waits_for_the_host_when_idle():
    printer = build_printer(with_bed=False)
    pacer = Pacer(printer, MAX, idle_speed=0)
    assert pacer.advance() is None and printer.time_s == 0
    printer.receive(b"G4 S3\n")
    waits = [pacer.advance() for _ in range(4)]
    assert waits == [0.0, 0.0, None, None]  # 1 s steps; G4 ends in the third
    assert printer.time_s == pytest.approx(3.0, abs=0.01)


# -- CLI errors: one message, exit 2 -------------------------------------------------------------------
@pytest.mark.slow
def test_bad_speed_exits_2_with_a_message():
    result = run_cli("--speed", "fast")
    assert result.returncode == 2
    assert "speed must be 'max' or a positive number" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow


def test_bad_scenario_file_exits_2_with_a_message(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("duration_s = -1\n")
    result = run_cli("--scenario", str(bad))
    assert result.returncode == 2
    assert result.stderr.startswith("twin-serial: error:") and "bad.toml" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow


def test_port_in_use_exits_2_with_a_message():
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        result = run_cli("--tcp", f"127.0.0.1:{port}")
    assert result.returncode == 2
    assert f"cannot listen on 127.0.0.1:{port}" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.slow


def test_settings_file_not_written_by_the_twin_is_refused_and_left_alone(tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("my printer's notes\n")
    result = run_cli("--settings", str(notes))
    assert result.returncode == 2 and "refusing to overwrite" in result.stderr
    assert "Traceback" not in result.stderr
    assert notes.read_text() == "my printer's notes\n"


def test_settings_file_m500_wrote_is_accepted(tmp_path):
    eeprom = tmp_path / "eeprom.json"
    printer = build_printer(settings=str(eeprom))
    printer.receive(b"M500\n")
    assert eeprom.exists()
    assert build_printer(settings=str(eeprom)).take_output().decode().count("stored settings retrieved") == 1


@pytest.mark.slow


def test_help_has_examples():
    result = run_cli("--help")
    assert result.returncode == 0 and "examples:" in result.stdout and "--idle-speed" in result.stdout
