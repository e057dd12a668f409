"""A user's printer.cfg as the twin MCU reads it (protocol/klipper_mcu/user_config.py): the chip, heaters,
thermistors, fan and axes on their pins; includes and the SAVE_CONFIG block; one-line refusals."""

from __future__ import annotations

import pytest

from protocol.klipper_mcu.printer_cfg import CONFIG_END, user_printer_cfg
from protocol.klipper_mcu.user_config import ConfigError, parse_pin, read_user_config

ENDER3 = """# This file contains pin mappings for the stock 2018 Creality Ender 3. To use
# this config, the firmware should be compiled for the AVR atmega1284p.
[stepper_x]
step_pin: PD7
dir_pin: !PC5
enable_pin: !PD6
microsteps: 16
rotation_distance: 40
endstop_pin: ^PC2
position_endstop: 0
position_max: 235

[stepper_z]
step_pin: PB3
dir_pin: PB2
enable_pin: !PA5
microsteps: 16
rotation_distance: 8
endstop_pin: ^PC4
position_endstop: 0.0
position_max: 250

[extruder]
step_pin: PB1
dir_pin: !PB0
heater_pin: PD5
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PA7  # the hotend's thermistor
control: pid
max_temp: 250

[heater_bed]
heater_pin: PD4
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PA6
pullup_resistor: 4600
max_temp: 130

[temperature_sensor board]
sensor_type: EPCOS 100K B57560G104F
sensor_pin: PA5

[fan]
pin: PB4

[mcu]
serial: /dev/ttyUSB0

[printer]
kinematics: cartesian
"""


def write(tmp_path, text, name="printer.cfg"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_ender3_board(tmp_path):
    config = read_user_config(write(tmp_path, ENDER3))
    assert config.chip.name == "atmega1284p" and config.serial == "/dev/ttyUSB0" and config.fan_pin == "PB4"
    hotend, bed = config.heaters
    assert (hotend.heater, hotend.heater_pin, hotend.sensor_pin, hotend.max_temp_c) == ("hotend", "PD5", "PA7", 250.0)
    assert (bed.heater, bed.pullup_ohm, bed.max_temp_c) == ("bed", 4600.0, 130.0)
    assert [s.pin for s in config.sensors] == ["PA5"]
    x, z = config.axes
    assert (x.step_pin, x.dir_inverted, x.endstop.name, x.endstop.inverted) == ("PD7", True, "PC2", False)
    assert x.step_mm == 40 / (200 * 16) and x.position_endstop_mm == 0 and not x.homes_positive
    assert z.step_mm == 8 / (200 * 16) and z.position_max_mm == 250


def test_the_chip_from_the_pins_where_the_config_does_not_say(tmp_path):
    text = ENDER3.replace("the firmware should be compiled for the AVR atmega1284p.", "the firmware should fit.")
    assert read_user_config(write(tmp_path, text)).chip.name == "atmega1284p"  # ports A-D: the smaller AVR
    assert read_user_config(write(tmp_path, text.replace("PB4", "PL5"))).chip.name == "atmega2560"
    assert read_user_config(write(tmp_path, text), "atmega2560").chip.name == "atmega2560"


def test_includes_and_the_save_config_block(tmp_path):
    write(tmp_path, "[fan]\npin: PB3\n", "fan.cfg")
    text = ENDER3.replace("[fan]\npin: PB4\n", "[include fan.cfg]\n")
    text += "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n#*# [heater_bed]\n#*# max_temp = 110\n"
    config = read_user_config(write(tmp_path, text))
    assert config.fan_pin == "PB3" and config.heaters[1].max_temp_c == 110.0


@pytest.mark.parametrize(("change", "message"), [
    (("[mcu]\nserial: /dev/ttyUSB0\n", ""), "no [mcu] section"),
    (("atmega1284p", "sam4e8e"), "cannot serve an MCU compiled for sam4e8e; it serves atmega2560"),
    (("PD7", "PL7"), "pins the atmega1284p does not have: PL7"),
    (("rotation_distance: 40", "rotation_distance: forty"), "[stepper_x] rotation_distance: 'forty' is not a number"),
    (("[printer]", "[printer"), "printer.cfg"),
])
def test_a_config_the_twin_cannot_serve_is_one_line(tmp_path, change, message):
    with pytest.raises(ConfigError) as error:
        read_user_config(write(tmp_path, ENDER3.replace(*change)))
    assert message in str(error.value) and "\n" not in str(error.value)


def test_pins_lose_their_modifiers():
    assert parse_pin("^!PC2") == parse_pin("!^PC2") == parse_pin("! PC2")
    assert parse_pin("^!PC2").inverted and not parse_pin("~PC2").inverted and parse_pin("!!PC2").inverted is False
    assert parse_pin("probe:z_virtual_endstop").mcu == "probe"


def test_the_served_config_changes_only_the_serial_line():
    served = user_printer_cfg(ENDER3, "/run/twin/mcu").splitlines()
    original = ENDER3.splitlines()
    assert served[-1] == CONFIG_END and len(served) == len(original) + 1
    assert [(a, b) for a, b in zip(original, served) if a != b] == [("serial: /dev/ttyUSB0", "serial: /run/twin/mcu")]
    assert "serial: /run/twin/mcu" in user_printer_cfg("[mcu]\nbaud: 250000\n[printer]\n", "/run/twin/mcu")


def test_a_thermistor_the_twin_does_not_simulate_is_one_line(tmp_path):
    from protocol.klipper_mcu.board import TwinBoard
    from tests.klipper_mcu.host import NO_SCENARIO

    config = read_user_config(write(tmp_path, ENDER3.replace("sensor_type: EPCOS 100K B57560G104F\nsensor_pin: PA7",
                                                             "sensor_type: MAX6675\nsensor_pin: PA7")))
    with pytest.raises(ConfigError, match=r"\[extruder\] sensor_type 'MAX6675': the twin simulates these thermistors"):
        TwinBoard.for_config(config, NO_SCENARIO)


def test_a_tmc_virtual_endstop_is_its_drivers_diag_pin(tmp_path):
    """Sensorless homing: klippy homes on the driver's DIAG output, which rises where the carriage stalls."""
    text = ENDER3.replace("endstop_pin: ^PC2", "endstop_pin: tmc2209_stepper_x:virtual_endstop") + """
[tmc2209 stepper_x]
uart_pin: PC6
diag_pin: ^PC3
"""
    x, _ = read_user_config(write(tmp_path, text)).axes
    assert (x.endstop.name, x.endstop.inverted, x.endstop.mcu, x.position_endstop_mm) == ("PC3", False, "mcu", 0)
