"""Marlin's MPC on the compiled batch: each lane is the float32 ``MpcController`` on its own ``Twin``,
reading for reading, through a heat-up and the part fan and the filament flow that it reads from the
board (its model's loss terms)."""

from __future__ import annotations

import numpy as np

from firmware_port.marlin.mpc import MpcController, mpc_controller
from tests.twin.test_batch_paths import TARGET_AT_S, TARGET_C, _assert_lane_is_the_twin
from twin.batch import BatchTwin
from twin.batch_kernel import KERNEL_ENV
from twin.engine import Twin
from twin.plants import make_plant

DURATION_S = 200.0
FAN_AT_S, FAN_SPEED = 120.0, 128  # M106 S128: the plant's fan 128/255
FLOW_AT_S, FLOW_MM_S = 150.0, 4.0


def _mpcs() -> list[MpcController]:
    """Configuration.h's model, and two identified elsewhere: a slower sensor, a lossier block."""
    return [MpcController(), mpc_controller(40.0, 14.0, 0.12, 0.08, 0.12, 0.0056),
            mpc_controller(40.0, 20.0, 0.30, 0.05, 0.09, 0.0056)]


def _scalar(controller: MpcController) -> Twin:
    twin = Twin([make_plant("hotend_cartridge")], "mpc", controllers=[controller])
    twin.schedule(TARGET_AT_S, lambda t: t.board.set_target(0, TARGET_C))
    twin.schedule(FAN_AT_S, lambda t: setattr(t.board, "fan_speed", FAN_SPEED))
    twin.schedule(FLOW_AT_S, lambda t: setattr(t, "flow_mm_s", FLOW_MM_S))
    twin.run_until(DURATION_S)
    return twin


def _set_inputs(batch: BatchTwin, fan: float, flow_mm_s: float) -> None:
    """What the scalar twin's board does to its plant: the fan M106 drives, the filament fed."""
    for plant in batch.plants:
        plant.set_inputs(fan, flow_mm_s, plant.ambient_c)


def test_mpc_lanes_equal_the_scalar_mpc():
    batch = BatchTwin(make_plant("hotend_cartridge"), _mpcs(), kernel="numba")
    batch.schedule(TARGET_AT_S, lambda b: b.set_target(TARGET_C))
    batch.schedule(FAN_AT_S, lambda b: _set_inputs(b, FAN_SPEED / 255, 0.0))
    batch.schedule(FLOW_AT_S, lambda b: _set_inputs(b, FAN_SPEED / 255, FLOW_MM_S))
    batch.run_until(DURATION_S)
    for lane, controller in enumerate(_mpcs()):
        twin = _scalar(controller)
        _assert_lane_is_the_twin(batch, lane, twin)
        scalar, lanes = twin.board.hotend.controller, batch.lanes.control.controllers[lane]
        for name in ("ambient_c", "block_c", "sensor_c", "e_position_steps"):
            assert getattr(lanes, name) == getattr(scalar, name), name
        assert scalar.e_position_steps > 0  # the flow moved the E stepper the model reads
    duty = batch.result().hotend.duty
    assert not np.array_equal(duty[:, 0], duty[:, 1])


def test_either_kernel_takes_the_mpc_but_not_a_float64_one(monkeypatch):
    """kernel='numpy' runs a law that reads the board on the loop (tests/twin/test_fallback.py checks the
    readings); the float64 build is not the firmware's."""
    for kernel in ("numba", "numpy"):
        monkeypatch.setenv(KERNEL_ENV, kernel)
        assert BatchTwin.accepts(MpcController())
    assert not BatchTwin.accepts(MpcController(dtype=np.float64))
