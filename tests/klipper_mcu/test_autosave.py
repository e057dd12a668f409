"""autosave.py: TWIN_APPLY's write of printer.cfg's SAVE_CONFIG block, on files, against the rules of
klippy 0.12's configfile.py (its SAVE_CONFIG): the block merged, duplicates commented out, an
include's option refused, a hand-edited block left alone, the old file kept."""

from __future__ import annotations

import pytest

from tools.klipper_host.autosave import AUTOSAVE_HEADER, AutosaveError, pid_options, save_options, split_autosave

CONFIG = """[mcu]
serial: /dev/ttyUSB0

[extruder]
heater_pin: PB4
control: pid
pid_Kp: 22.2
pid_Ki: 1.08
pid_Kd: 114 # from PID_CALIBRATE
max_temp: 300
"""
OLD_BLOCK = AUTOSAVE_HEADER + """#*# [heater_bed]
#*# control = pid
#*# pid_kp = 70.000
#*#
#*# [extruder]
#*# pid_kp = 1.000
"""


def test_the_gains_go_into_the_block_and_the_regular_ones_are_commented_out(tmp_path):
    path = tmp_path / "printer.cfg"
    path.write_text(CONFIG)
    backup = save_options(path, "extruder", pid_options(12.71507, 0.480843, 35.40152))
    assert backup.read_text() == CONFIG and backup.name.startswith("printer-") and backup.suffix == ".cfg"
    regular, block = split_autosave(path.read_text())
    assert "#control: pid\n#pid_Kp: 22.2\n#pid_Ki: 1.08\n#pid_Kd: 114 # from PID_CALIBRATE\nmax_temp: 300" in regular
    assert block.split() == ["[extruder]", "control", "=", "pid", "pid_kp", "=", "12.715", "pid_ki", "=", "0.481",
                             "pid_kd", "=", "35.402"]
    assert not (tmp_path / "printer_autosave.cfg").exists()


def test_an_existing_block_keeps_its_other_sections_and_takes_the_new_values(tmp_path):
    path = tmp_path / "printer.cfg"
    path.write_text(CONFIG + OLD_BLOCK)
    save_options(path, "extruder", pid_options(1.5, 2.5, 3.5))
    text = path.read_text()
    assert text.count(AUTOSAVE_HEADER.strip()) == 1
    _, block = split_autosave(text)
    assert "[heater_bed]\ncontrol = pid\npid_kp = 70.000" in block
    assert "[extruder]\npid_kp = 1.500\ncontrol = pid\npid_ki = 2.500\npid_kd = 3.500" in block


def test_an_option_set_in_an_included_file_is_refused_and_nothing_is_written(tmp_path):
    (tmp_path / "hotend.cfg").write_text("[extruder]\npid_Kp: 20\n")
    path = tmp_path / "printer.cfg"
    path.write_text("[include hotend.cfg]\n" + CONFIG.replace("pid_Kp: 22.2\n", ""))
    before = path.read_text()
    with pytest.raises(AutosaveError, match=r"\[extruder\] pid_kp is set in the included hotend.cfg"):
        save_options(path, "extruder", pid_options(1.0, 2.0, 3.0))
    assert path.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["hotend.cfg", "printer.cfg"]


def test_a_hand_edited_block_is_left_alone(tmp_path):
    path = tmp_path / "printer.cfg"
    path.write_text(CONFIG + OLD_BLOCK + "[extruder]\n")
    with pytest.raises(AutosaveError, match="edited by hand"):
        save_options(path, "extruder", pid_options(1.0, 2.0, 3.0))
    assert path.read_text() == CONFIG + OLD_BLOCK + "[extruder]\n"
