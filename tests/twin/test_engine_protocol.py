"""The engine protocol (twin/engine_protocol.py): Twin, BatchTwin, KlipperTwin and KlipperBatch, and Stacks of the
single twins, driven by the same code: handles, a target, events on the plants, run, the result's shape, halted and
the trips. The trip: one lane's heater gives 0.5 W (a cartridge that has all but failed), so Marlin's heating watch
("Heating failed") and Klipper's verify_heater ("not heating at expected rate") stop that lane and no other.

Then the same runner on a batch and on a Stack of its lanes' single twins gives the same readings, duty, halted
lanes and trips: the protocol keeps the lanes-equal-their-twins guarantee (tests/twin/test_batch_paths.py,
test_klipper_batch.py) for a tuner that writes one runner."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_port.marlin.mpc import MpcController, mpc_controller
from firmware_port.marlin.pid import HOTEND_GAINS, PidFixed
from twin.batch import BatchTwin
from twin.engine import Twin
from twin.engine_protocol import Engine, Heater, Stack, Trip
from twin.klipper_batch import KlipperBatch
from twin.klipper_twin import KlipperTwin, extruder_setup
from twin.plants import make_plant

PRESET = "hotend_cartridge"
DEAD_POWER_W = 0.5  # the failed cartridge: a few tenths of a degree in a minute
TARGET_C = 200
FAN_AT_S = 30.0
RUN_S = 100.0  # past two of Marlin's 40 s heating watches (the first starts from the board's 0 C before its first reading)
MARLIN_TRIP = "Heating failed"
KLIPPER_TRIP = "Heater extruder not heating at expected rate"


def _plants(dead: list[bool]) -> list:
    return [make_plant(PRESET, power_w=DEAD_POWER_W) if d else make_plant(PRESET) for d in dead]


def _twin(plant) -> Twin:
    return Twin([plant], "pid", controllers=[PidFixed(HOTEND_GAINS)])


def _klipper_twin(plant) -> KlipperTwin:
    return KlipperTwin([extruder_setup(plant)])


BUILD = {  # lanes (dead or not) -> engine; the single twins take one lane
    "Twin": lambda dead: _twin(_plants(dead)[0]),
    "BatchTwin": lambda dead: BatchTwin(_plants(dead), [PidFixed(HOTEND_GAINS) for _ in dead]),
    "KlipperTwin": lambda dead: _klipper_twin(_plants(dead)[0]),
    "KlipperBatch": lambda dead: KlipperBatch([extruder_setup(p) for p in _plants(dead)]),
    "Stack of Twins": lambda dead: Stack([_twin(p) for p in _plants(dead)]),
    "Stack of KlipperTwins": lambda dead: Stack([_klipper_twin(p) for p in _plants(dead)]),
}
SINGLE = ("Twin", "KlipperTwin")
TRIP = {"Twin": MARLIN_TRIP, "BatchTwin": MARLIN_TRIP, "Stack of Twins": MARLIN_TRIP}


def _fan_on(plant) -> None:
    plant.set_inputs(1.0, plant.flow_mm_s, plant.ambient_c)


def _run(engine: Engine):
    """The one runner: target, a fan kick on the plants, run; readings as (rows, lanes)."""
    engine.hotend.target_c = TARGET_C
    engine.schedule_plants(FAN_AT_S, _fan_on)
    result = engine.run(RUN_S)
    hotend = result.hotend
    rows = len(result.t_s)
    return hotend.measured_c.reshape(rows, -1), hotend.duty.reshape(rows, -1), np.atleast_1d(engine.halted), \
        engine.trips()


@pytest.mark.parametrize("kind", BUILD)
def test_every_engine_follows_the_protocol(kind):
    dead = [True] if kind in SINGLE else [False, True]
    engine = BUILD[kind](dead)
    assert isinstance(engine, Engine) and engine.n_lanes == len(dead) and engine.time_s == 0.0
    assert kind.split()[-1].rstrip("s") in repr(engine)

    handle = engine.hotend
    assert isinstance(handle, Heater) and handle.name == "hotend" and list(engine.handles) == ["hotend"]
    assert len(handle.controllers) == len(dead)
    handle.target_c = TARGET_C
    assert engine.hotend.target_c == TARGET_C

    seen: list[float] = []
    engine.schedule(10.0, lambda e: seen.append(e.time_s))
    fanned: list = []
    engine.schedule_plants(FAN_AT_S, lambda plant: (_fan_on(plant), fanned.append(plant)))
    result = engine.run(RUN_S)

    assert engine.time_s == pytest.approx(RUN_S, abs=1e-3) and seen and all(t == pytest.approx(10.0, abs=1e-3) for t in seen)
    assert len(fanned) == len(dead) and all(plant.fan == 1.0 for plant in fanned)
    hotend = result.hotend
    rows = len(result.t_s)
    shape = (rows,) if kind in SINGLE else (rows, len(dead))
    assert rows > 50 and all(getattr(hotend, f).shape == shape for f in ("target_c", "measured_c", "duty"))
    assert np.all(np.diff(result.t_s) > 0) and np.all(hotend.target_c[0] == TARGET_C)

    if kind in SINGLE:
        assert engine.halted is True
    else:
        assert engine.halted.tolist() == [False, True]
    lane = len(dead) - 1
    assert engine.trips() == [Trip(lane, "hotend", TRIP.get(kind, KLIPPER_TRIP))]
    working = hotend.measured_c.reshape(rows, -1)[:, 0]
    assert kind in SINGLE or working[-1] > 100.0  # the working lane heats on


@pytest.mark.parametrize("batch, stack", [("BatchTwin", "Stack of Twins"), ("KlipperBatch", "Stack of KlipperTwins")])
def test_a_batch_and_a_stack_of_its_lanes_twins_give_the_same_run(batch, stack):
    """Readings and duty equal reading by reading, the same lanes halted for the same reasons."""
    dead = [False, True, False]
    lanes, twins = _run(BUILD[batch](dead)), _run(BUILD[stack](dead))
    np.testing.assert_array_equal(lanes[0], twins[0])
    np.testing.assert_array_equal(lanes[1], twins[1])
    assert lanes[2].tolist() == twins[2].tolist() == dead
    assert lanes[3] == twins[3] == [Trip(1, "hotend", TRIP.get(batch, KLIPPER_TRIP))]


def test_plant_events_reach_what_a_twin_board_reads_as_on_the_lanes():
    """MPC reads the part fan (M106) and the E stepper: on a Twin the plants' new inputs move both, as the
    lanes' compiled loop reads them from the plant, so a Stack of MPC twins is the MPC batch reading for reading."""
    def mpcs():
        return [MpcController(), mpc_controller(40.0, 14.0, 0.12, 0.08, 0.12, 0.0056)]

    def run(engine: Engine) -> np.ndarray:
        engine.hotend.target_c = TARGET_C
        engine.schedule_plants(40.0, lambda p: p.set_inputs(128 / 255, 0.0, p.ambient_c))
        engine.schedule_plants(60.0, lambda p: p.set_inputs(p.fan, 4.0, p.ambient_c))
        return engine.run(90.0).hotend.measured_c

    stack = Stack([Twin([make_plant(PRESET)], "mpc", controllers=[mpc]) for mpc in mpcs()])
    np.testing.assert_array_equal(run(BatchTwin(make_plant(PRESET), mpcs())), run(stack))
    assert all(mpc.e_position_steps > 0 for mpc in stack.hotend.controllers)
    assert all(twin.board.fan_speed == 128 for twin in stack.engines)


def test_a_stack_holds_single_twins_only():
    with pytest.raises(ValueError, match="lane 0: a stack holds single twins, not an engine of 2 lanes"):
        Stack([BUILD["BatchTwin"]([False, False])])
    with pytest.raises(ValueError, match="at least one"):
        Stack([])
