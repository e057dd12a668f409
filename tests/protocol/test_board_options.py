"""What a board without a bed, a read-only EEPROM file or a negative gain gets: Marlin's answers,
never a traceback."""

from __future__ import annotations

import logging
import re

import pytest

from protocol.build import build_printer


def _send(printer, *lines: str) -> list[str]:
    for line in lines:
        printer.receive(line.encode() + b"\n")
    printer.run_until_idle(600)
    return printer.take_output().decode().splitlines()


@pytest.mark.parametrize("line", ["M140 S60", "M190 S60", "M190 R60"])
def test_a_bedless_board_does_not_know_the_bed_commands(line, caplog):
    """Without HAS_HEATED_BED Marlin compiles no M140/M190: parser.unknown_command_warning()."""
    caplog.set_level(logging.ERROR)
    printer = build_printer(with_bed=False)
    printer.take_output()
    assert _send(printer, line) == [f'echo:Unknown command: "{line}"', "ok"]
    assert printer.internal_errors == 0 and caplog.records == []


def test_m301_stores_and_echoes_negative_gains_as_marlin_does():
    printer = build_printer()
    printer.take_output()
    assert _send(printer, "M301 P-5", "M301") == ["ok", "echo:  M301 P-5.00 I2.06 D48.23", "ok"]
    assert _send(printer, "M304 I-0.5 D-10", "M304") == ["ok", "echo:  M304 P86.92 I-0.50 D-10.00", "ok"]
    assert _send(printer, "M105")[-1].startswith("ok T:")


def test_gains_beyond_the_fixed_point_range_are_clamped_out_loud():
    printer = build_printer()
    printer.take_output()
    lines = _send(printer, "M301 P5000 I-300", "M301")
    assert lines == ["echo:M301 gains clamped to the twin's range (|P| <= 1000, |I| <= 100, |D| <= 5000): "
                     "P1000.00 I-100.00 D48.23", "ok", "echo:  M301 P1000.00 I-100.00 D48.23", "ok"]


def test_a_controller_that_refuses_negative_gains_keeps_its_own():
    printer = build_printer(firmware="fuzzy_pid")
    printer.take_output()
    lines = _send(printer, "M301 P-5", "M301")
    assert lines[0] == "echo:M301 refused: the fuzzy-PID takes base gains >= 0, not kp < 0"
    assert lines[2] == "echo:  M301 P22.20 I1.08 D114.00"


def test_an_eeprom_write_failure_is_answered_as_marlin_answers_it(tmp_path):
    """The AVR HAL's write_data prints STR_ERR_EEPROM_WRITE; settings.save() ignores the result,
    so its report follows, then ok, and the printer keeps serving."""
    folder = tmp_path / "gone"
    folder.mkdir()
    printer = build_printer(settings=str(folder / "eeprom.json"))
    printer.take_output()
    folder.rmdir()  # the file can no longer be written
    lines = _send(printer, "M500", "M105")
    assert lines[0] == "echo:Error writing to EEPROM!"
    assert re.fullmatch(r"echo:Settings Stored \(\d+ bytes; crc \d+\)", lines[1])
    assert lines[2] == "ok" and lines[3].startswith("ok T:")


@pytest.mark.parametrize("path, reason", [("/proc/heater-twin.json", "cannot be written"),
                                          ("/nonexistent-dir/eeprom.json", "its directory does not exist")])
def test_a_settings_file_that_cannot_be_written_is_refused_at_start(path, reason):
    with pytest.raises(ValueError, match=reason):
        build_printer(settings=path)


def test_checking_a_new_settings_file_leaves_nothing_behind(tmp_path):
    build_printer(settings=str(tmp_path / "eeprom.json"))
    assert list(tmp_path.iterdir()) == []
