"""The printer's own gains: read from what a log states (an M303 capture's last printed gains, a klippy.log's
config dump, a PID_CALIBRATE result) or given as --current-gains in Marlin's or Klipper's words."""

import pytest

from tools.logs import load_log
from tools.tuning.gains import Gains
from tools.tuning.reference import from_log, parse_gains


@pytest.mark.parametrize("text", ["22.2,1.08,114", "22.2 1.08 114", "M301 P22.2 I1.08 D114",
                                  "echo:  M301 P22.20 I1.08 D114.00", "M304 P22.2 I1.08 D114",
                                  "pid_Kp=22.2 pid_Ki=1.08 pid_Kd=114", "pid_Kp: 22.2\npid_Ki: 1.08\npid_Kd: 114"])
def test_gains_in_marlins_or_klippers_words(text):
    assert parse_gains(text) == Gains(22.2, 1.08, 114.0)


@pytest.mark.parametrize("text, why", [("22.2,1.08", "give P,I,D"), ("M301 P22.2 I-1 D114", "ki=-1.0"),
                                       ("fast please", "give P,I,D")])
def test_anything_else_is_one_line_naming_the_flag(text, why):
    with pytest.raises(ValueError, match="--current-gains") as error:
        parse_gains(text)
    assert why in str(error.value) and "\n" not in str(error.value)


def test_what_the_captures_state(hardware_logs):
    bed = from_log(load_log(hardware_logs / "m303_bed_artillery_genius_pro_S60_configs641.txt"), "heater_bed")
    assert bed is not None and bed.gains == Gains(22.17, 1.36, 241.26)  # its final Kp/Ki/Kd lines
    partial = from_log(load_log(hardware_logs / "m303_hotend_artillery_genius_pro_S210_configs641_partial.txt"),
                       "extruder")
    assert partial is not None and partial.gains == Gains(11.07, 1.22, 25.13)  # the last it printed
    assert from_log(load_log(hardware_logs / "m303_bed_artillery_genius_pro_S60_configs641.txt"), "extruder") is None
    stats = load_log(hardware_logs / "klippy_stats_icodextrin_ender5_creality427.csv")
    assert from_log(stats, "extruder").gains == Gains(24.831, 1.346, 114.532)
    assert from_log(stats, "heater_bed").gains == Gains(66.429, 1.197, 921.707)
    results = load_log(hardware_logs / "klipper_pid_calibrate_results_collection.txt")
    assert from_log(results, "heater_bed", 0).gains == Gains(65.914712, 1.33973, 810.750951)
    assert from_log(results, "extruder", 2).gains == Gains(18.441, 0.64, 132.774)
    # an M303 of fewer than three cycles prints zeros: no gains a printer runs on
    assert from_log(load_log(hardware_logs / "m303_hotend_C1_degenerate_marlin6316.txt"), "extruder") is None
