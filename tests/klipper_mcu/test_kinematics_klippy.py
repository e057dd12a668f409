"""Klipper's own corexy and BLTouch example configs on the twin MCU, homed by the registry's klippy with
only [mcu]'s serial line changed: corexy's switches press where (a + b) / 2 and (a - b) / 2 reach them, and
Z homes onto a BLTouch that klippy deploys, checks and stows over its servo pin (issue 39, item 4)."""

from __future__ import annotations

import re

import pytest

from tests.klipper_mcu.test_printer_cfg import endstops, example_config

pytestmark = pytest.mark.slow


def kinematic_position(api) -> dict[str, float]:
    lines = api.gcode("GET_POSITION")
    (line,) = [each for each in lines if "kinematic:" in each]
    return {axis: float(value) for axis, value in re.findall(r"([XYZ]):(-?[\d.]+)", line)}


def test_a_corexy_homes_each_axis_onto_its_switch(klipper):
    session = klipper("--printer-cfg", str(example_config("printer-tronxy-x5s-2018.cfg")))  # corexy, atmega1284p
    api = session.api
    api.gcode("G28")
    assert endstops(api) == {"x": "TRIGGERED", "y": "TRIGGERED", "z": "TRIGGERED"}
    position = kinematic_position(api)
    # at the position_endstops, within the steps a trigger's 4 samples (60 us) allow at the homing speeds
    assert max(abs(position[axis] - at) for axis, at in (("X", 0.0), ("Y", 0.0), ("Z", 0.5))) < 0.05, position
    api.gcode("G1 X50 F3000")  # x alone: both belts turn; y's switch stays pressed
    api.gcode("M400")
    assert endstops(api) == {"x": "open", "y": "TRIGGERED", "z": "TRIGGERED"}
    api.gcode("G1 Y50 Z10 F3000")
    api.gcode("M400")
    assert endstops(api) == {"x": "open", "y": "open", "z": "open"}


def test_z_homes_onto_a_bltouch(klipper):
    session = klipper("--printer-cfg", str(example_config("printer-creality-cr10s-pro-v2-2020.cfg")))  # z_offset 2
    api = session.api
    api.gcode("G28")
    assert api.query("toolhead")["toolhead"]["homed_axes"] == "xyz"
    assert "BLTouch failed" not in session.klippy_log()
    api.gcode("G1 Z10 F600")
    lines = [each for each in api.gcode("PROBE") if "probe at" in each]  # one per sample (the config's samples: 2)
    assert len(lines) == 2, lines
    for line in lines:  # the probe triggers at the height G28 set as its z_offset (a Z step is 2.5 um)
        assert abs(float(line.rsplit("z=", 1)[1]) - 2.0) < 0.01, lines
