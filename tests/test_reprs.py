"""Every public class says what it is when printed (a notebook's view): a ``__repr__`` of its own or a base's,
never object's ``<... object at 0x...>``; and the reprs of the objects a user meets (engines, handles, plants,
controllers, the board's parts, the serial printer's) run and name what they hold."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from typing import Protocol

import numpy as np
import pytest

import firmware_port
import protocol
import tools
import twin
from firmware_port.fuzzy_pi import FuzzyPi, FuzzyPiFloat
from firmware_port.fuzzy_pid import FuzzyPid, FuzzyPidFloat
from firmware_port.lane_law import ScalarLanes
from firmware_port.marlin.autotune import Autotune
from firmware_port.marlin.bangbang import BangBangBed, BangBangHotend
from firmware_port.marlin.mpc import MpcController
from firmware_port.marlin.pid import KP_Q12, HOTEND_GAINS, PidFixed, PidLanes
from firmware_port.marlin.pid_float import PidFloat
from protocol.build import build_printer
from protocol.corruption import RxCorruptor
from protocol.klipper_mcu.codec import BlockReader
from protocol.pacing import Pacer
from protocol.transcript import Transcript
from tests.klipper_mcu.host import TestHost
from twin import BatchTwin, KlipperBatch, KlipperTwin, Stack, Twin, make_plant
from twin.klipper_twin import extruder_setup

PACKAGES = (firmware_port, twin, protocol, tools)
# The tuning layer's classes (Evaluator, ideal.Pid, optim.result.Ledger) are its owner's to give a __repr__.
NOT_YET: tuple[str, ...] = ()
OBJECT_REPR = re.compile(r"object at 0x")


def _public_classes() -> list[type]:
    found = []
    for package in PACKAGES:
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            if info.name.startswith(NOT_YET) or info.name.endswith("__main__"):
                continue
            module = importlib.import_module(info.name)
            found += [cls for name, cls in vars(module).items() if inspect.isclass(cls) and
                      cls.__module__ == module.__name__ and not name.startswith("_")]
    return found


def _is_base_only(cls: type) -> bool:
    """A protocol, an abstract base or a mixin whose subclasses all say what they are."""
    subclasses = cls.__subclasses__()
    return Protocol in cls.__mro__ or inspect.isabstract(cls) or \
        bool(subclasses) and all(sub.__repr__ is not object.__repr__ for sub in subclasses)


def test_every_public_class_has_a_repr():
    classes = _public_classes()
    assert len(classes) > 150
    missing = [f"{cls.__module__}.{cls.__qualname__}" for cls in classes
               if cls.__repr__ is object.__repr__ and not _is_base_only(cls)]
    assert not missing


def _twins():
    t = Twin.create("pid", hotend="hotend", bed="bed")
    t.hotend.target_c = 200
    t.run(5.0)
    board = t.board
    return [t, t.hotend, board, board.hotend, board.adc, board.pwm, board.hotend.runaway, board.hotend.watch,
            board.hotend.temp_range, t.console, t.plants[0], t.sensors[0], t._events,
            t.plants[0].model]


def _batches():
    batch = BatchTwin(make_plant("hotend"), [PidFixed(HOTEND_GAINS), PidFixed(HOTEND_GAINS)])
    batch.run(2.0)
    klipper = KlipperTwin([extruder_setup()])
    klipper.run(2.0)
    channel = klipper.channels["extruder"]
    lanes = KlipperBatch([extruder_setup(), extruder_setup()])
    stack = Stack([Twin([make_plant("hotend")]), Twin([make_plant("hotend")])])
    return [batch, batch.lanes, batch.lanes.control, batch.hotend, klipper, klipper.hotend, channel.heater,
            channel.heater.control, channel.verify, channel.pwm, lanes, stack]


def _controllers():
    return [PidFixed(), PidFloat(), PidLanes([HOTEND_GAINS]), KP_Q12, BangBangHotend(), BangBangBed(True),
            MpcController(), FuzzyPi(), FuzzyPiFloat(), FuzzyPid(), FuzzyPidFloat(),
            ScalarLanes([BangBangHotend()]),
            Autotune(0, 200, 5, False, Twin.create().console, lambda: "", lambda what: None, 275)]


def _serial(tmp_path):
    printer = build_printer(with_bed=False)
    host = TestHost()
    transcript = Transcript(tmp_path / "t.log")
    try:
        return [printer, printer.reader, printer.link, printer.planner, printer.eeprom, Pacer(printer),
                RxCorruptor(0.1), BlockReader(), host.board, host.mcu, host.board.fan, transcript]
    finally:
        transcript.close()


@pytest.mark.parametrize("objects", [_twins, _batches, _controllers, _serial])
def test_what_a_user_meets_says_what_it_is(objects, tmp_path):
    made = objects(tmp_path) if objects is _serial else objects()
    for thing in made:
        text = repr(thing)
        assert not OBJECT_REPR.search(text), text
        assert type(thing).__name__ in text or isinstance(thing, np.ndarray), text
