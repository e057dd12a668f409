"""The board's ReadsBoard hook (firmware_port/controller.py): a controller that reads the board is
given, right before each update, the soft-PWM amount in force, the part fan and the E stepper;
the same in both engines. Controllers without the hook are called as before."""

from __future__ import annotations

import math

from firmware_port.controller import BoardInputs, ReadsBoard, is_tunable
from firmware_port.marlin.constants import E_STEPS_PER_MM
from firmware_port.marlin.pid import PidFixed
from twin.clock import TICK_S
from twin.engine import Twin
from twin.plants import make_plant


class Recorder:
    """Outputs a fixed cycle of values; records what it was given before each update."""

    check_interval_ms = None

    def __init__(self) -> None:
        self.given: list[BoardInputs | None] = []
        self.outputs: list[int] = []
        self.pending: BoardInputs | None = None
        self.ticks: list[int] = []  # the board's tick at each update
        self.board = None

    def reset(self) -> None:
        self.pending = None

    def read_board(self, inputs: BoardInputs) -> None:
        self.pending = inputs

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        self.given.append(self.pending)
        self.ticks.append(self.board.ticks)
        self.pending = None
        self.outputs.append((37 * len(self.outputs)) % 256)
        return self.outputs[-1]


def _twin(recorder: Recorder, engine: str = "fast") -> Twin:
    twin = Twin([make_plant("hotend")], "pid", controllers=[recorder], engine=engine)
    recorder.board = twin.board
    return twin


def _run(engine: str, seconds: float = 20.0) -> tuple[Recorder, int]:
    """Heat for ``seconds``; from 5 s on, fan 128 and 3 mm/s of filament. Returns the tick the flow began."""
    recorder = Recorder()
    twin = _twin(recorder, engine)
    twin.board.set_target(0, 200)
    twin.run(5.0)
    twin.board.fan_speed = 128
    twin.flow_mm_s = 3.0
    flow_tick = twin.tick
    twin.run(seconds - 5.0)
    return recorder, flow_tick


def test_each_update_is_preceded_by_the_amount_fan_and_e_stepper():
    recorder, flow_tick = _run("fast")
    assert isinstance(recorder, ReadsBoard)
    assert all(inputs is not None for inputs in recorder.given)
    assert recorder.given[0].amount == 0
    # the amount in force is the last output >> 1 (nothing else wrote the soft PWM meanwhile)
    assert [g.amount for g in recorder.given[1:]] == [out >> 1 for out in recorder.outputs[:-1]]
    fans = {g.fan_speed for g in recorder.given}
    assert fans == {0, 128}
    # the E stepper: the whole steps fed (3 mm/s at 500 steps/mm) by the tick the main loop ran at
    expected = [max(0, math.floor(3.0 * (tick - flow_tick) * TICK_S * E_STEPS_PER_MM)) for tick in recorder.ticks]
    assert [g.e_position_steps for g in recorder.given] == expected
    assert expected[-1] > 3.0 * 14.5 * E_STEPS_PER_MM


def test_both_engines_give_the_same_inputs():
    fast, _ = _run("fast", 8.0)
    reference, _ = _run("reference", 8.0)
    assert fast.given == reference.given and fast.ticks == reference.ticks


def test_a_retraction_moves_the_stepper_back_and_a_reset_zeroes_it():
    twin = _twin(Recorder())
    twin.flow_mm_s = 2.0
    twin.run(2.0)
    forward = twin.board.e_position_steps
    twin.flow_mm_s = -2.0
    twin.run(1.0)
    assert 0 < twin.board.e_position_steps < forward
    twin.reset_board()
    twin.flow_mm_s = 0.0
    twin.run(1.0)
    assert twin.board.e_position_steps == 0  # counted from the reset, nothing fed since


def test_controllers_without_the_hook_are_untouched():
    pid = PidFixed()
    assert not isinstance(pid, ReadsBoard) and is_tunable(pid)
    twin = Twin([make_plant("hotend")], "pid", controllers=[pid])
    twin.board.set_target(0, 200)
    twin.run(3.0)
    assert twin.board.amount(0) == 127  # PID drives full power far below the target, as before
