"""The compiled laws in the loop: a twin whose controllers run in simavr traces exactly as the fast engine.

``engine="avr"`` is the fast engine with each heater's controller replaced by its AVR build
(firmware_port/avr/controllers.py). Same scenario, seed and noise: every trace row and event is
equal, and so is each controller's state at the end (the MCU's against the Python port's).
"""

from __future__ import annotations

import pytest

from firmware_port.avr.controllers import AvrController, AvrTunable
from firmware_port.avr.laws import law_for
from firmware_port.marlin.pid import HOTEND_GAINS, PidFixed, PidGains
from tools.cli.sim import main
from twin.build import build_twin
from twin.engine import Twin
from twin.scenario import PRESETS, with_overrides

pytestmark = pytest.mark.avr

SCENARIO = with_overrides(PRESETS["heat_hold"], duration_s=90, seed=5)
NEW_GAINS = PidGains(15.0, 0.8, 90.0)


def run(firmware: str, engine: str, with_bed: bool = True) -> Twin:
    """Heat both heaters, then on the way kick the fan, move the hotend's target and (a PID) set
    new gains, which the avr engine writes into the MCU's RAM (M301)."""
    twin = build_twin(SCENARIO, firmware, engine=engine, with_bed=with_bed, noise_lsb=0.5)
    twin.schedule(40, lambda t: t.board.set_gains(0, NEW_GAINS) if t.board.has_gains(0) else None)
    twin.schedule(50, lambda t: setattr(t.board, "fan_speed", 255))
    twin.schedule(70, lambda t: t.board.set_target(0, 180))
    twin.run_until(SCENARIO.duration_s)
    return twin


@pytest.mark.parametrize("firmware", ["pid", "bangbang", "fuzzy_pi", "fuzzy_pid"])
def test_trace_equals_the_fast_engine(firmware, avr_toolchain) -> None:
    fast, avr = run(firmware, "fast"), run(firmware, "avr")
    assert len(avr.trace.rows) == len(fast.trace.rows) > 500
    assert avr.trace.rows == fast.trace.rows
    assert avr.trace.events == fast.trace.events
    if avr.board.has_gains(0):  # M301 reached the MCU
        assert isinstance(avr.board.heaters[0].controller, AvrTunable)
        assert avr.hotend.gains == fast.hotend.gains == NEW_GAINS
    for python, compiled in zip(fast.board.heaters, avr.board.heaters):
        assert isinstance(compiled.controller, AvrController)
        law = compiled.controller.law
        assert law is law_for(python.controller)
        names = [name for name, _ in law.state_fields]
        assert compiled.controller.state() == dict(zip(names, law.state(python.controller)))


def test_twin_sim_engine_avr_writes_the_fast_engines_trace(capsys, tmp_path, avr_toolchain) -> None:
    """The acceptance command, on 120 s instead of 600 (the full 600 s run is the same command)."""
    csv = {}
    for engine in ("fast", "avr"):
        path = tmp_path / f"{engine}.csv"
        code = main(["--engine", engine, "--firmware", "pid", "--no-bed", "--duration", "120", "--no-plot",
                     "--csv", str(path), "--out", str(tmp_path)])
        assert code == 0, capsys.readouterr().err
        csv[engine] = path.read_text()
    assert csv["avr"] == csv["fast"]
    assert len(csv["avr"].splitlines()) > 700


def test_a_firmware_without_an_avr_build_is_a_clear_error(capsys, tmp_path, avr_toolchain) -> None:
    code = main(["--engine", "avr", "--firmware", "pid_float", "--no-bed", "--duration", "10", "--no-plot",
                 "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "PidFloat has no AVR build" in err and "PidFixed" in err


def test_injected_controllers_are_kept(avr_toolchain) -> None:
    """engine="avr" replaces the firmware's controllers, not the ones a caller injects."""
    injected = PidFixed(HOTEND_GAINS)
    twin = build_twin(SCENARIO, "pid", engine="avr", with_bed=False, controllers=[injected])
    assert twin.board.heaters[0].controller is injected
