"""The printer's mechanics behind the twin MCU's steppers (protocol/klipper_mcu/axes.py, user_config.py's
axes): a switch presses where klippy's kinematics puts its rail (corexy x = (a + b) / 2, y = (a - b) / 2),
a delta's towers are carriages of their own with stepper_a's defaults, and the first clock a switch
closes is the first step that takes the rail there."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.klipper_mcu.axes import Carriage, Move, Switch
from protocol.klipper_mcu.board import TwinBoard
from protocol.klipper_mcu.user_config import AxisPins, Pin, StepperPins, read_user_config
from tests.klipper_mcu.host import NO_SCENARIO
from tests.klipper_mcu.test_user_config import ENDER3, write

STEP_MM = 0.01
A = StepperPins("stepper_x", "PA0", False, STEP_MM)
B = StepperPins("stepper_y", "PA1", True, STEP_MM)  # a dir_pin with "!": its MCU count runs against klippy's mm


def corexy_switch(axis: str, carriages: dict[str, Carriage]) -> Switch:
    """x (or y) on a corexy of 0..200 mm, its switch at 0: from klippy's calc_position."""
    terms = ((A, 0.5), (B, 0.5 if axis == "x" else -0.5))
    pins = AxisPins(f"stepper_{axis}", "PA0", False, Pin("PC2"), STEP_MM, 0.0, 0.0, 200.0, False, terms)
    return Switch(pins, lambda pin: carriages.setdefault(pin, Carriage(A if pin == "PA0" else B)))


def test_corexy_x_presses_when_both_belts_carry_it_home_and_not_on_a_y_move():
    carriages: dict[str, Carriage] = {}
    x, y = corexy_switch("x", carriages), corexy_switch("y", carriages)
    a, b = carriages["PA0"], carriages["PA1"]
    # x from 100 to 0: a and b each -100 mm in klippy's mm; b's MCU count runs +1 per klippy -0.01 mm
    a.queue(Move(0, 100, 20000, 0, -1), 0)
    b.queue(Move(0, 100, 20000, 0, +1), 0)
    assert x.pressed_from(0) == 10000 * 100 and not x.pressed(10000 * 100 - 1)
    assert y.pressed_from(0) is None  # y stays at 100 all along
    a.stop(0)
    b.stop(0)
    # y from 100 to 0: a -100 mm, b +100 mm; x stays at 100
    a.queue(Move(0, 100, 20000, 0, -1), 0)
    b.queue(Move(0, 100, 20000, 0, -1), 0)
    assert y.pressed_from(0) == 10000 * 100 and x.pressed_from(0) is None


@given(st.integers(1, 5000), st.integers(1, 5000), st.integers(50, 400), st.integers(50, 400), st.integers(0, 3000))
def test_the_first_pressed_clock_is_the_first_step_that_gets_there(count_a, count_b, interval_a, interval_b, delay_b):
    """Both belts towards x=0 at their own rates (a monotone approach): the clock found is the first of all the
    steps' clocks at which x <= 0 (a brute force over every step of both moves)."""
    carriages: dict[str, Carriage] = {}
    switch = corexy_switch("x", carriages)
    switch.axis = AxisPins("stepper_x", "PA0", False, Pin("PC2"), STEP_MM, 75.0, 0.0, 200.0, False, switch.axis.terms)
    move_a, move_b = Move(0, interval_a, count_a, 0, -1), Move(delay_b, interval_b, count_b, 0, +1)
    carriages["PA0"].queue(move_a, 0)
    carriages["PA1"].queue(move_b, 0)
    clocks = sorted({move_a.step_clock(k) for k in range(1, count_a + 1)}
                    | {move_b.step_clock(k) for k in range(1, count_b + 1)})
    expected = next((c for c in clocks
                     if 100 - 0.5 * STEP_MM * (move_a.steps_by(c) + move_b.steps_by(c)) <= 75.0), None)
    assert switch.pressed_from(0) == expected


CORE = ENDER3.replace("[stepper_z]", """[stepper_y]
step_pin: PC6
dir_pin: !PC7
microsteps: 16
rotation_distance: 40
endstop_pin: ^PC3
position_endstop: 0
position_max: 220

[stepper_z]""")


ENDER3_Z = ENDER3[ENDER3.index("[stepper_z]"):ENDER3.index("\n[extruder]")]
DELTA = ENDER3.replace("[stepper_x]", "[stepper_a]").replace(ENDER3_Z, """[stepper_b]
step_pin: PB3
dir_pin: PB2
microsteps: 16
rotation_distance: 40
endstop_pin: ^PC3

[stepper_c]
step_pin: PB5
dir_pin: PB6
microsteps: 16
rotation_distance: 40
endstop_pin: ^PC4
""").replace("position_endstop: 0\nposition_max: 235", "position_endstop: 300\narm_length: 215").replace(
    "kinematics: cartesian", "kinematics: delta\ndelta_radius: 100")


def test_a_deltas_towers_are_carriages_of_their_own_with_stepper_as_defaults(tmp_path):
    config = read_user_config(write(tmp_path, DELTA))
    a, b, c = config.axes
    assert [axis.section for axis in config.axes] == ["stepper_a", "stepper_b", "stepper_c"]
    for axis in (a, b, c):  # klippy: stepper_b and _c take stepper_a's position_endstop; position_max is it
        assert (axis.position_endstop_mm, axis.position_min_mm, axis.position_max_mm) == (300, 0, 300)
        assert axis.homes_positive and [(s.section, w) for s, w in axis.terms] == [(axis.section, 1.0)]
    assert config.probe is None


def test_corexy_rails_from_the_config(tmp_path):
    text = CORE.replace("kinematics: cartesian", "kinematics: corexy")
    x, y, z = read_user_config(write(tmp_path, text)).axes
    assert [(s.section, w) for s, w in x.terms] == [("stepper_x", 0.5), ("stepper_y", 0.5)]
    assert [(s.section, w) for s, w in y.terms] == [("stepper_x", 0.5), ("stepper_y", -0.5)]
    assert [(s.section, w) for s, w in z.terms] == [("stepper_z", 1.0)]
    board = TwinBoard.for_config(read_user_config(write(tmp_path, text)), NO_SCENARIO)
    switch_y, level = board.endstop("PC3")
    assert level == 1 and isinstance(switch_y, Switch)
    board.carriage("PD7").position = -8000  # stepper_x's dir is inverted: +100 mm of a
    assert switch_y.rail.at_mm(0) == 110 + 50 and not switch_y.pressed(0)
    board.carriage("PC6").position = -16000  # +200 mm of b: y = 110 + (100 - 200) / 2
    assert switch_y.rail.at_mm(0) == 60



@pytest.mark.parametrize(("kinematics", "expected"), [
    # klippy/kinematics/*.py calc_position, each rail's coordinate from the steppers' positions
    ("cartesian", {"x": {"x": 1.0}, "y": {"y": 1.0}, "z": {"z": 1.0}}),
    ("corexz", {"x": {"x": 0.5, "z": 0.5}, "y": {"y": 1.0}, "z": {"x": 0.5, "z": -0.5}}),
    ("hybrid_corexy", {"x": {"x": 1.0, "y": 1.0}, "y": {"y": 1.0}, "z": {"z": 1.0}}),
    ("hybrid_corexz", {"x": {"x": 1.0, "z": 1.0}, "y": {"y": 1.0}, "z": {"z": 1.0}}),
])
def test_each_kinematics_weights_its_rails(tmp_path, kinematics, expected):
    config = read_user_config(write(tmp_path, CORE.replace("kinematics: cartesian", f"kinematics: {kinematics}")))
    got = {axis.section[-1]: {s.section[-1]: w for s, w in axis.terms} for axis in config.axes}
    assert got == expected
