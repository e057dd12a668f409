"""The virtual printer's commands and replies, Marlin 2.1 as the reference describes it."""

import re

import numpy as np
import pytest

from firmware_port.marlin.constants import TEMP_HYSTERESIS_C
from firmware_port.marlin.pid import PidGains
from protocol.lines import with_checksum
from protocol.link import BYTE_TICKS
from protocol.printer import VirtualPrinter
from protocol.settings import Eeprom
from twin.build import build_twin
from twin.clock import TICK_S
from twin.scenario import parse_scenario

SERIAL = parse_scenario('duration_s = 86400\nname = "serial"\n', "serial")
STATES = r" T:\d+\.\d\d /\d+\.\d\d B:\d+\.\d\d /\d+\.\d\d @:\d+ B@:\d+"


def make_printer(firmware="pid", eeprom=None, scenario=SERIAL, **options):
    printer = VirtualPrinter(lambda: build_twin(scenario, firmware), eeprom=eeprom, **options)
    printer.take_output()
    return printer


def send(printer, *lines, run=True):
    for line in lines:
        printer.receive(line.encode() + b"\n")
    if run:
        printer.run_until_idle()
    return printer.take_output().decode().splitlines()


def test_banner_after_reset():
    printer = make_printer()
    printer.reset()
    lines = printer.take_output().decode().splitlines()
    assert lines[:3] == ["start", " External Reset", "Marlin 2.1.2.1"]
    assert "echo:  M301 P19.96 I2.06 D48.23" in lines  # the stock build's gains (firmwares.py STOCK_HOTEND_GAINS)


def test_m105_one_line_that_is_its_own_ok_with_real_readings():
    lines = send(make_printer(), "M105")
    assert len(lines) == 1
    assert re.fullmatch(r"ok" + STATES, lines[0])
    assert re.fullmatch(r"ok T:2[45]\.\d\d /0\.00 B:2[45]\.\d\d /0\.00 @:0 B@:0", lines[0])


def test_m104_clamps_to_maxtemp_minus_15_and_m140():
    printer = make_printer()
    assert send(printer, "M104 S300", "M140 S200") == ["ok", "ok"]
    assert printer.twin.board.hotend.target_c == 260 and printer.twin.board.bed.target_c == 140


def test_m109_reports_every_second_then_residency_then_ok():
    printer = make_printer()
    lines = send(printer, "M109 S200")
    reports = [line for line in lines if line.startswith(" T:")]
    assert all(re.fullmatch(STATES + r" W:(\?|\d+)", line) for line in reports)
    assert lines[-1] == "ok"
    # W counts down from the residency start (10 s, or 13 s when reached on the first loop)
    counts = [int(line.rsplit("W:", 1)[1]) for line in reports if not line.endswith("W:?")]
    assert counts[-1] == 0 and counts[0] in (9, 10, 13)
    assert "echo:busy: processing" in lines
    assert 60 < printer.time_s < 300
    assert abs(printer.twin.board.hotend.temp_q5 / 32 - 200) < 1.0


def test_m109_s_does_not_wait_for_cooling_but_r_does():
    printer = make_printer()
    send(printer, "M109 S150")
    start = printer.time_s
    assert send(printer, "M109 S100")[-1] == "ok" and printer.time_s - start < 1
    lines = send(printer, "M109 R120")
    assert lines[-1] == "ok" and printer.time_s - start > 10
    # the residency ends 10 s after the reading came within TEMP_WINDOW, never beyond TEMP_HYSTERESIS since
    assert abs(printer.twin.board.hotend.temp_q5 / 32 - 120) <= TEMP_HYSTERESIS_C


def test_m108_breaks_a_heat_wait():
    printer = make_printer()
    printer.receive(b"M109 S200\n")
    printer.run_for(5)
    printer.receive(b"M108\n")
    printer.run_until_idle()
    lines = printer.take_output().decode().splitlines()
    assert lines[-2:] == ["ok", "ok"]  # M109 ends, then M108's own ok
    assert printer.time_s < 10


def test_m155_auto_reports_while_the_clock_runs():
    printer = make_printer()
    assert send(printer, "M155 S2") == ["ok"]
    printer.run_for(10.0)
    lines = printer.take_output().decode().splitlines()
    assert len(lines) == 5 and all(re.fullmatch(STATES, line) for line in lines)
    send(printer, "M155 S0")
    printer.run_for(10.0)
    assert printer.take_output() == b""


def test_fans_and_extrusion_reach_the_plant():
    printer = make_printer()
    send(printer, "M106 S128")
    assert printer.twin.board.fan_speed == 128
    send(printer, "M107")
    assert printer.twin.board.fan_speed == 0
    send(printer, "M83", "G1 E10 F120", run=False)  # 10 mm at 2 mm/s: 5 s of 2 mm/s flow
    printer.run_for(1.0)  # the G1 arrives 1.2 ms (14 bytes) after the M83, then its ok
    assert printer.twin.flow_mm_s == pytest.approx(2.0)
    printer.run_for(5.0)
    assert printer.twin.flow_mm_s == 0.0
    assert send(printer, "M114")[-2].startswith("X:0.00 Y:0.00 Z:0.00 E:10.00")


def test_m400_and_g4_take_virtual_time():
    printer = make_printer()
    start = printer.time_s
    assert send(printer, "G4 P1500") == ["ok"]
    assert printer.time_s - start == pytest.approx(1.5, abs=0.002)
    send(printer, "G91", "G1 X100 F6000", "M400")  # 100 mm at 100 mm/s
    # the move starts when its line has arrived behind the G91's: 14 bytes at 115200 baud, 1.2 ms,
    # up to the next tick (1.024 ms), and ends on a tick
    assert printer.time_s - start == pytest.approx(2.5 + 14 * BYTE_TICKS * TICK_S, abs=0.002)


def test_busy_lines_every_2_s_and_m113():
    printer = make_printer()
    lines = send(printer, "G4 S5")
    assert lines == ["echo:busy: processing", "echo:busy: processing", "ok"]
    assert send(printer, "M113") == ["echo:M113 S2", "ok"]
    assert send(printer, "M113 S0", "G4 S5") == ["ok", "ok"]


def test_m301_m304_set_and_report_user_units():
    printer = make_printer()
    assert send(printer, "M301") == ["echo:  M301 P19.96 I2.06 D48.23", "ok"]
    assert send(printer, "M301 P15.5 I1.2 D80", "M301") == ["ok", "echo:  M301 P15.50 I1.20 D80.00", "ok"]
    assert send(printer, "M304 P40 I2 D300", "M304") == ["ok", "echo:  M304 P40.00 I2.00 D300.00", "ok"]
    # Marlin parses floats as float32: I1.2 is stored as 1.2000000476837158
    assert printer.twin.board.hotend.controller.gains == PidGains(15.5, float(np.float32(1.2)), 80.0)


def test_settings_survive_a_restart_in_the_file(tmp_path):
    path = tmp_path / "eeprom.json"
    printer = make_printer(eeprom=Eeprom(path))
    send(printer, "M301 P15.5 I1.2 D80")
    stored = send(printer, "M500")
    assert re.fullmatch(r"echo:Settings Stored \(\d+ bytes; crc \d+\)", stored[0]) and stored[1] == "ok"
    again = VirtualPrinter(lambda: build_twin(SERIAL, "pid"), eeprom=Eeprom(path))
    banner = again.take_output().decode().splitlines()
    assert re.fullmatch(r"echo:V87 stored settings retrieved \(\d+ bytes; crc \d+\)", banner[5])
    assert send(again, "M301") == ["echo:  M301 P15.50 I1.20 D80.00", "ok"]
    assert send(again, "M502", "M301")[:2] == ["echo:Hardcoded Default Settings Loaded", "ok"]
    assert send(again, "M501", "M503")[-3:] == ["echo:; Bed PID:", "echo:  M304 P86.92 I10.40 D484.20", "ok"]
    assert send(again, "M301") == ["echo:  M301 P15.50 I1.20 D80.00", "ok"]


def test_m303_prints_marlins_autotune_and_u1_applies_it():
    printer = make_printer()
    lines = send(printer, "M303 E0 S210 C8 U1")
    assert lines[0] == "PID Autotune start"
    assert lines[-1] == "ok" and lines[-5].startswith("PID Autotune finished!")
    ku_lines = [line for line in lines if " Ku: " in line]
    assert len(ku_lines) == 6 and lines.count(" Classic PID ") == 6
    assert "echo:busy: processing" not in lines  # M303's loop does not call idle()
    kp, ki, kd = (float(line.rsplit(" ", 1)[1]) for line in lines[-4:-1])
    assert send(printer, "M301") == [f"echo:  M301 P{kp:.2f} I{ki:.2f} D{kd:.2f}", "ok"]


def test_m303_errors():
    printer = make_printer()
    assert send(printer, "M303 E1 S200") == ["PID Autotune failed! Bad heater id", "ok"]
    assert send(printer, "M303 E0 S300") == ["PID Autotune failed! Temperature too high", "ok"]
    bang = make_printer("bangbang")
    assert send(bang, "M303 E0 S200") == ["PID Autotune failed! Bad heater id", "ok"]
    assert send(bang, "M301") == ['echo:Unknown command: "M301"', "ok"]


def test_unknown_commands_and_motion_are_acknowledged():
    printer = make_printer()
    assert send(printer, "G999", "M9999 S1", "G28", "G1 X10 Y10 F3000", "M84") == [
        'echo:Unknown command: "G999"', "ok", 'echo:Unknown command: "M9999 S1"', "ok", "ok", "ok", "ok"]


def test_empty_and_comment_lines_get_no_reply():
    assert send(make_printer(), "", "; a comment", "   ", "M400 ; wait") == ["ok"]


def test_checksum_error_asks_for_a_resend_and_the_line_runs_once():
    printer = make_printer()
    good = with_checksum("M104 S150", 1)
    bad = good[:-1] + str((int(good[-1]) + 1) % 10)
    assert send(printer, bad) == ["Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]
    assert send(printer, good) == ["ok"]
    assert send(printer, with_checksum("M105", 3)) == [
        "Error:Line Number is not Last Line Number+1, Last Line: 1", "Resend: 2", "ok"]
    assert send(printer, "N2 M105") == ["Error:No Checksum with line number, Last Line: 1", "Resend: 2", "ok"]
    assert printer.twin.board.hotend.target_c == 150


def test_no_ok_after_resend_option():
    printer = make_printer(ok_after_resend=False)
    assert send(printer, "N1 M105*1") == ["Error:checksum mismatch, Last Line: 0", "Resend: 1"]


def test_m112_kills_and_nothing_answers_until_reset():
    printer = make_printer()
    # M112 acts when its line arrives: the M104 queued behind a running G4 never runs
    printer.receive(b"G4 S10\nM104 S200\nM112\nM105\n")
    printer.run_until_idle()
    lines = printer.take_output().decode().splitlines()
    assert lines == ["echo:M112 Shutdown", "Error:Printer halted. kill() called!"]
    assert printer.twin.board.hotend.target_c == 0
    assert send(printer, "M105") == []
    printer.reset()
    assert printer.take_output().decode().startswith("start\n")
    assert re.fullmatch("ok" + STATES, send(printer, "M105")[0])


def test_thermal_runaway_during_a_wait_halts_with_marlins_text():
    scenario = parse_scenario('duration_s = 86400\nname = "s"\n[[fault]]\nat_s = 150\nheater = "hotend"\n'
                              'kind = "heater_disconnected"\n', "s")
    printer = make_printer(scenario=scenario)
    assert send(printer, "M109 S200")[-1] == "ok"
    lines = send(printer, "G4 S200")
    assert lines[-4:] == ["Error:Thermal Runaway, system stopped! Heater_ID: E0", "",
                          "echo:THERMAL RUNAWAY", "Error:Printer halted. kill() called!"]
    assert send(printer, "M105") == []


def test_m115_names_the_twin():
    lines = send(make_printer(), "M115")
    assert lines[0].startswith("FIRMWARE_NAME:Marlin 2.1.2.1 (heater-twin digital twin) ")
    assert "Cap:AUTOREPORT_TEMP:1" in lines and "Cap:EEPROM:1" in lines and lines[-1] == "ok"


def test_m104_for_a_missing_extruder():
    assert send(make_printer(), "M104 T1 S200") == ["echo:M104 Invalid extruder 1", "ok"]


# -- values beyond Marlin's widths, errors inside commands ---------------------------------------------
HUGE = "9" * 41  # beyond float32: strtod gives inf


@pytest.mark.parametrize("line", [f"G4 S{HUGE}", *(pytest.param(line, marks=pytest.mark.slow) for line in (
    f"G0 X{HUGE}", f"G1 Y{HUGE}", f"G1 Z-{HUGE}")), f"G1 E{HUGE}", f"G1 X1 F{HUGE}", "G4 P4294967296", "G4 S-5"])
def test_values_beyond_the_widths_are_answered_not_fatal(line):
    printer = make_printer()
    assert send(printer, line)[-1] == "ok"
    assert send(printer, "M105")[-1].startswith("ok T:")  # still serving


def test_g92_beyond_float32_then_m114_prints_what_arduino_prints():
    printer = make_printer()
    send(printer, f"G92 X{HUGE} Y-{HUGE}")
    assert send(printer, "M114")[0].startswith("X:inf Y:inf Z:0.00")  # printFloat: sign, then 'inf'


def test_a_dwell_beyond_2_31_ms_has_passed_at_once_as_in_marlins_pending():
    printer = make_printer()
    start_s = printer.time_s
    send(printer, "G4 P2147483649")  # PENDING() compares int32: that deadline is in the past
    send(printer, f"G4 S{HUGE}")  # inf x 1000 cast to uint32: beyond 2^31 too
    assert printer.time_s - start_s < 0.1
    send(printer, "G4 P1500")
    assert printer.time_s - start_s == pytest.approx(1.5, abs=0.01)


def test_an_absurd_move_lasts_a_bounded_time_and_m410_stops_it():
    printer = make_printer()
    send(printer, "G1 X1 F0.0001", run=False)  # 80 steps at MINIMAL_STEP_RATE (120/s), not 10 hours
    assert printer.planner.blocks[0].duration_s == pytest.approx(80 / 120)
    send(printer, f"G1 X{HUGE}", run=False)
    printer.run_for(0.01)  # its 49 bytes arrive behind the first line's
    assert len(printer.planner.blocks) == 2
    printer.receive(b"M410\n")  # quickstop: acted on when the line arrives
    printer.run_for(0.001)
    assert not printer.planner.blocks


def test_a_command_that_raises_is_answered_and_the_printer_keeps_serving(monkeypatch, caplog):
    from protocol import commands

    def broken(p, cmd):
        raise RuntimeError("a bug")

    monkeypatch.setitem(commands.HANDLERS, ("M", 115), broken)
    printer = make_printer()
    assert send(printer, "M115") == ["Error:internal error in 'M115': RuntimeError", "ok"]
    assert printer.internal_errors == 1 and "a bug" in caplog.text
    assert send(printer, "M105")[-1].startswith("ok T:")


def test_line_numbers_at_the_int32_edge_as_marlins_queue_cpp():
    """last_N is a long: N2147483648 reads as LONG_MAX (strtol saturates) and lands in the
    'already in transit' window, so Marlin 2.1 drops it silently; a host that wraps as C does
    sends N-2147483648, which is last_N + 1 in 32 bits."""
    printer = make_printer()
    assert send(printer, with_checksum("M110 N2147483647", 0)) == ["ok"]
    assert send(printer, with_checksum("M105", 2147483648)) == []
    assert send(printer, with_checksum("M105", -2147483648))[-1].startswith("ok T:")
    assert printer.reader.last_n == -2147483648


def test_the_resend_after_the_int32_edge_wraps_as_the_board_prints_it():
    printer = make_printer()
    send(printer, with_checksum("M110 N2147483647", 0))
    assert send(printer, "N5 M105*1")[:2] == ["Error:Line Number is not Last Line Number+1, Last Line: 2147483647",
                                             "Resend: -2147483648"]
