"""M306 over the serial layer (protocol/mpc_commands.py): set and report in Marlin 2.1.2.1's format,
M306 T as a blocking command, M500/M501/M502/M503 carrying MPC_t, and M306 lines read from text."""

from __future__ import annotations

import json
from collections import deque

import pytest

from firmware_port.marlin.mpc import MpcConstants
from protocol.mpc_commands import mpc_constants_from_text
from protocol.printer import VirtualPrinter
from protocol.settings import Eeprom, Settings
from protocol.build import build_printer

DEFAULT_REPORT = "  M306 E0 P40.00 C16.70 R0.2200 A0.0680 F0.0970 H0.0056"


def send(printer: VirtualPrinter, *lines: str) -> list[str]:
    """The printer's replies to the lines, each run to its end."""
    for line in lines:
        printer.receive(line.encode() + b"\n")
        printer.run_until_idle()
    return printer.take_output().decode().splitlines()


@pytest.fixture
def mpc() -> VirtualPrinter:
    printer = build_printer(firmware="mpc", with_bed=False)
    printer.take_output()
    return printer


def test_the_banner_reports_the_model_last(mpc):
    printer = build_printer(firmware="mpc")
    banner = printer.take_output().decode().splitlines()
    assert banner[-4:] == ["echo:; Bed PID:", "echo:  M304 P10.00 I0.02 D305.40", "echo:; Model predictive control:",
                           "echo:" + DEFAULT_REPORT]


def test_m306_reports_for_replay_and_sets_in_marlins_order(mpc):
    assert send(mpc, "M306") == [DEFAULT_REPORT, "ok"]
    assert send(mpc, "M306 E0") == [DEFAULT_REPORT, "ok"]  # E alone: a report
    assert send(mpc, "M306 P35 C12.345 R0.1 H0.0036", "M306") == [
        "ok", "  M306 E0 P35.00 C12.35 R0.1000 A0.0680 F0.0970 H0.0036", "ok"]
    # F is stored as its difference to A: an A set later moves F; on one line F follows A
    assert send(mpc, "M306 A0.1", "M306")[1] == "  M306 E0 P35.00 C12.35 R0.1000 A0.1000 F0.1290 H0.0036"
    assert send(mpc, "M306 F0.2 A0.05", "M306")[1] == "  M306 E0 P35.00 C12.35 R0.1000 A0.0500 F0.2000 H0.0036"
    assert send(mpc, "M306 P", "M306") == ["ok", "  M306 E0 P35.00 C12.35 R0.1000 A0.0500 F0.2000 H0.0036", "ok"]


def test_another_extruder_is_refused_and_a_pid_build_does_not_know_m306(mpc):
    assert send(mpc, "M306 E1 P30", "M306") == ["?(E)xtruder index out of range (0-0).", "ok", DEFAULT_REPORT, "ok"]
    pid = build_printer(firmware="pid")
    pid.take_output()
    assert send(pid, "M306", "M306 T") == ['echo:Unknown command: "M306"', "ok", 'echo:Unknown command: "M306 T"', "ok"]
    assert not any("Model predictive" in line for line in send(pid, "M503"))


def test_m500_stores_the_model_m501_loads_it_m502_restores_the_builds(tmp_path):
    path = tmp_path / "eeprom.json"
    printer = build_printer(firmware="mpc", settings=str(path))
    printer.take_output()
    stored = send(printer, "M306 C12.5 R0.15 A0.05 F0.08", "M500")
    assert stored[1].startswith("echo:Settings Stored (") and stored[1].endswith(")")
    image = json.loads(path.read_text())
    assert MpcConstants(**image["hotend_mpc"]).m306() == "M306 E0 P40.00 C12.50 R0.1500 A0.0500 F0.0800 H0.0056"
    assert send(printer, "M502", "M306")[-2] == DEFAULT_REPORT
    loaded = send(printer, "M501", "M306")
    assert loaded[0].startswith("echo:V87 stored settings retrieved (")
    assert loaded[-2] == "  M306 E0 P40.00 C12.50 R0.1500 A0.0500 F0.0800 H0.0056"
    assert send(printer, "M503")[-3:] == ["echo:; Model predictive control:",
                                          "echo:  M306 E0 P40.00 C12.50 R0.1500 A0.0500 F0.0800 H0.0056", "ok"]
    again = build_printer(firmware="mpc", settings=str(path))  # a reset loads it
    assert again.take_output().decode().splitlines()[-1] == "echo:  M306 E0 P40.00 C12.50 R0.1500 A0.0500 F0.0800 H0.0056"


def test_a_pid_image_on_an_mpc_build_keeps_the_builds_model(tmp_path):
    path = tmp_path / "eeprom.json"
    pid = build_printer(firmware="pid", settings=str(path))
    send(pid, "M500")
    assert "hotend_mpc" not in json.loads(path.read_text())  # a PID build's image is as before
    mpc = build_printer(firmware="mpc", settings=str(path))
    assert mpc.take_output().decode().splitlines()[-1] == "echo:" + DEFAULT_REPORT
    assert Settings.from_bytes(Eeprom(path).read()).hotend_mpc is None


def test_m306_t_runs_without_idle_lines_and_keeps_the_result(mpc):
    send(mpc, "M155 S1")
    start_s = mpc.time_s
    tune = send(mpc, "M306 T")
    # its loop never calls idle(): no busy lines, and its own report once a second, no M155 ones
    assert not any("busy" in line for line in tune)
    assert sum(line.startswith(" T:") for line in tune) <= mpc.time_s - start_s + 1
    tune += send(mpc, "M306", "M114")  # (M155's reports resume while these lines cross the wire)
    found = {line.split(" ")[0]: line.split(" ")[1] for line in tune if line.startswith("MPC_")}
    report = tune[tune.index("MPC_AMBIENT_XFER_COEFF_FAN255 " + found["MPC_AMBIENT_XFER_COEFF_FAN255"]) + 2]
    assert report == (f"  M306 E0 P40.00 C{found['MPC_BLOCK_HEAT_CAPACITY']} R{found['MPC_SENSOR_RESPONSIVENESS']} "
                      f"A{found['MPC_AMBIENT_XFER_COEFF']} F{found['MPC_AMBIENT_XFER_COEFF_FAN255']} H0.0056")
    # homed, at MPC_TUNING_POS, then raised to MPC_TUNING_END_Z
    assert "X:100.00 Y:100.00 Z:10.00 E:0.00 Count X:8000 Y:8000 Z:4000" in tune


def test_m306_t_finishes_the_moves_before_it_starts(mpc):
    mpc.receive(b"G1 X50 E5 F300\nM306 T\n")  # a 10 s move
    mpc.run_for(5.0)
    waiting = mpc.take_output().decode().splitlines()  # homing waits for it (idle() runs: busy lines)
    assert waiting[0] == "ok" and set(waiting[1:]) <= {"echo:busy: processing"} and mpc.planner.blocks
    replies = [line for line in send(mpc, "M114") if line != "echo:busy: processing"]
    assert replies[0] == "MPC Autotune start for E0"
    assert replies[-2] == "X:100.00 Y:100.00 Z:10.00 E:5.00 Count X:8000 Y:8000 Z:4000"
    assert mpc.planner.blocks == deque() and mpc.twin.flow_mm_s == 0.0


def test_m108_interrupts_m306_t(mpc):
    mpc.receive(b"M306 T\n")
    mpc.run_for(30.0)  # heating
    replies = send(mpc, "M108", "M105")
    assert "MPC Autotune interrupted!" in replies
    assert replies[-1] == "ok T:" + replies[-1].split("ok T:")[1] and " /0.00 @:0" in replies[-1]


def test_an_m306_line_is_read_from_any_text():
    fit = ("fit: two_node on segment 0\n"
           "  Marlin:  M306 P40.00 C15.43 R0.0406 A0.0931 F0.0931\n"
           "           M301 P1.928 I0.0224 D22.9\n")
    assert mpc_constants_from_text(fit).m306() == "M306 E0 P40.00 C15.43 R0.0406 A0.0931 F0.0931 H0.0056"
    report = "M306 T\n  M306 E0 P30.00 C12.00 R0.1500 A0.0500 F0.0800 H0.0036\nok\n"
    assert mpc_constants_from_text(report) == MpcConstants.from_m306(30.0, 12.0, 0.15, 0.05, 0.08, 0.0036)
    assert mpc_constants_from_text("M306 C20") == MpcConstants(block_heat_capacity_j_k=20.0)
    for text in ("", "M306", "M306 T", "M3060 P1", "M301 P1 I2 D3"):
        with pytest.raises(ValueError, match="no M306 line with constants"):
            mpc_constants_from_text(text)
