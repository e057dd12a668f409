"""Marlin 2.1.2.1's MPC law (firmware_port/marlin/mpc.py) on worked examples: the start-up
initialisation, the power it plans, the fan and filament feed-forward with its guards, the
ambient estimate's quirks, and MPC_t's M306 semantics and report text."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_port.controller import BoardInputs, ReadsBoard
from firmware_port.firmwares import build_controllers
from firmware_port.marlin.mpc import (
    MPC_DT_F32,
    MpcConstants,
    MpcController,
    mpc_controller,
)
from firmware_port.thermistor import TEMP_ONE

DT = float(MPC_DT_F32)
REL = 1e-5  # float32 against the same sums in double: a few roundings of 2^-24 each


def q5(temp_c: float) -> int:
    return round(temp_c * TEMP_ONE)


def step(mpc: MpcController, temp_c: float, target_c: int, amount: int = 0, fan: int = 0, e_steps: int = 0) -> int:
    mpc.read_board(BoardInputs(amount, fan, e_steps))
    return mpc.update(q5(temp_c), target_c)


def test_the_first_reading_starts_the_model_and_a_zero_pull_lowers_the_ambient():
    mpc = MpcController()
    assert isinstance(mpc, ReadsBoard) and math.isnan(mpc.block_c)
    out = step(mpc, 25.0, 200)
    assert float(mpc.block_c) == float(mpc.sensor_c) == 25.0
    # the pull is exactly 0 and the heater off and steady: Marlin's `delta > 0 ? max : min` moves it down
    assert float(mpc.pull_c) == 0.0
    assert float(mpc.ambient_c) == pytest.approx(25.0 - DT, rel=REL)
    assert out == 255  # 175 C below the target: (200 - 25) C/2 s is far beyond the heater's 40 W

    hot = MpcController()
    step(hot, 40.0, 0)
    # capped at 30 C; the block cools towards it, the reading pulls up: at least MIN_AMBIENT_CHANGE up
    assert float(hot.pull_c) > 0
    assert float(hot.ambient_c) == pytest.approx(30.0 + max(float(hot.pull_c), DT), rel=REL)


def test_the_planned_power_reaches_the_target_in_two_seconds_and_holds_the_loss():
    c = MpcConstants()
    mpc = MpcController(c)
    step(mpc, 200.0, 200, amount=60)
    mpc.block_c = mpc.sensor_c = np.float32(199.0)
    mpc.ambient_c = np.float32(25.0)
    out = step(mpc, 199.0, 200, amount=60)
    # the model's step from 199 C at amount 60, then the pull (0 here: the reading is the model)
    block = 199.0 + (60 * c.heater_power_w * DT / 127 + (25.0 - 199.0) * c.ambient_xfer_w_k * DT) / c.block_heat_capacity_j_k
    sensor = 199.0 + (block - 199.0) * c.sensor_responsiveness_per_s * DT
    pull = (199.0 - sensor) * 0.5
    block, ambient = block + pull, 25.0 + (max(pull, DT) if pull > 0 else min(pull, -DT))
    power = (200 - block) * c.block_heat_capacity_j_k / 2 - (ambient - block) * c.ambient_xfer_w_k
    assert float(mpc.power_w) == pytest.approx(power, rel=REL)
    assert out == int(power * 254 / c.heater_power_w + 1)


def test_target_zero_plans_no_power_and_the_output_is_one():
    mpc = MpcController()
    assert step(mpc, 200.0, 0) == 1  # power 0 -> 0 * 254 / P + 1: soft PWM 1 >> 1 = 0
    assert float(mpc.power_w) == 0.0


def test_the_fan_raises_the_transfer_coefficient_from_a_to_f():
    c = MpcConstants()
    mpc = MpcController(c)
    for fan, expected in ((0, c.ambient_xfer_w_k), (255, c.fan_ambient_xfer_w_k),
                          (128, c.ambient_xfer_w_k + 128 / 255 * c.fan255_adjustment_w_k)):
        mpc.read_board(BoardInputs(0, fan, 0))
        assert float(mpc._transfer_coefficient()) == pytest.approx(expected, rel=REL)


def test_filament_feed_forward_counts_forward_steps_only_and_skips_jumps():
    c = MpcConstants()
    mpc = MpcController(c)
    step(mpc, 200.0, 200)
    assert mpc.e_position_steps == 0
    steps_per_reading = 164  # 2 mm/s for one MPC_dT at 500 steps/mm: 163.8
    mpc.read_board(BoardInputs(0, 0, steps_per_reading))
    k = float(mpc._transfer_coefficient())
    e_speed = steps_per_reading * 0.002 / DT
    assert k == pytest.approx(c.ambient_xfer_w_k + e_speed * c.filament_heat_capacity_j_k_mm, rel=REL)
    assert mpc.e_position_steps == steps_per_reading
    # a retraction adds nothing and is not taken: the next forward move pays it back first
    mpc.read_board(BoardInputs(0, 0, steps_per_reading - 100))
    assert float(mpc._transfer_coefficient()) == pytest.approx(c.ambient_xfer_w_k, rel=REL)
    assert mpc.e_position_steps == steps_per_reading
    mpc.read_board(BoardInputs(0, 0, steps_per_reading + 50))
    assert float(mpc._transfer_coefficient()) == pytest.approx(
        c.ambient_xfer_w_k + 50 * 0.002 / DT * c.filament_heat_capacity_j_k_mm, rel=REL)
    # a jump beyond the E axis' 25 mm/s (homing, G92) is taken without feed-forward
    jump = steps_per_reading + 50 + 5000
    mpc.read_board(BoardInputs(0, 0, jump))
    assert float(mpc._transfer_coefficient()) == pytest.approx(c.ambient_xfer_w_k, rel=REL)
    assert mpc.e_position_steps == jump


def test_the_ambient_estimate_moves_only_near_steady_state():
    mpc = MpcController()
    step(mpc, 100.0, 200)
    mpc.block_c = mpc.sensor_c = np.float32(100.0)
    before = float(mpc.ambient_c)
    step(mpc, 101.0, 200, amount=127)  # full power and heating fast: not steady, the output clipped
    assert float(mpc.ambient_c) == before
    step(mpc, 101.0, 200, amount=64)  # within 1..126: it moves with the pull (here > MIN_AMBIENT_CHANGE dT)
    assert float(mpc.ambient_c) == pytest.approx(before + float(mpc.pull_c), rel=REL)


def test_a_zero_or_absurd_constant_gives_an_output_in_range():
    for constants in (MpcConstants(heater_power_w=0.0), MpcConstants(block_heat_capacity_j_k=0.0),
                      MpcConstants(heater_power_w=-40.0), MpcConstants(ambient_xfer_w_k=1e38)):
        mpc = MpcController(constants)
        outs = [step(mpc, t, 200, amount=a) for t, a in ((25.0, 0), (30.0, 127), (35.0, 64))]
        assert all(0 <= out <= 255 for out in outs), constants


def test_m306_keeps_f_as_its_difference_to_a_and_reports_in_marlins_format():
    c = MpcConstants()
    assert c.m306() == "M306 E0 P40.00 C16.70 R0.2200 A0.0680 F0.0970 H0.0056"
    assert c.fan255_adjustment_w_k == float(np.float32(0.097) - np.float32(0.068))
    moved = c.with_m306(a=0.1)  # A alone: F moves with it (fan255_adjustment is what is stored)
    assert moved.m306() == "M306 E0 P40.00 C16.70 R0.2200 A0.1000 F0.1290 H0.0056"
    both = c.with_m306(f=0.2, a=0.05)  # F is applied after A, whatever the order on the line
    assert both.m306() == "M306 E0 P40.00 C16.70 R0.2200 A0.0500 F0.2000 H0.0056"
    assert c.with_m306(p=35, c=12.345, r=0.1, h=0.0036).m306() == \
        "M306 E0 P35.00 C12.35 R0.1000 A0.0680 F0.0970 H0.0036"


def test_the_factory_takes_m306s_vector_and_the_firmware_name_builds_it():
    mpc = mpc_controller(30.0, 12.0, 0.15, 0.05, 0.08, 0.0036)
    assert mpc.constants == MpcConstants.from_m306(30.0, 12.0, 0.15, 0.05, 0.08, 0.0036)
    assert mpc.constants.m306() == "M306 E0 P30.00 C12.00 R0.1500 A0.0500 F0.0800 H0.0036"
    assert mpc_controller().constants == MpcConstants()
    hotend, bed = build_controllers("mpc")
    assert isinstance(hotend, MpcController) and hotend.constants == MpcConstants()
    assert not isinstance(bed, ReadsBoard)  # the bed runs the default firmware's PID


def test_reset_forgets_the_model_not_the_constants():
    mpc = mpc_controller(30.0, 12.0, 0.15, 0.05, 0.08, 0.0036)
    step(mpc, 100.0, 200, e_steps=80)
    mpc.reset()
    assert math.isnan(mpc.block_c) and mpc.e_position_steps == 0
    assert mpc.constants.heater_power_w == 30.0 and mpc.defaults == mpc.constants
