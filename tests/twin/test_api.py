"""The public API: the README's example runs, controllers are injectable, one result type."""

import re
from pathlib import Path

import numpy as np
import pytest

import twin
from firmware_port.marlin.pid import PidFixed, PidGains
from protocol.printer import VirtualPrinter
from firmware_port.firmwares import STOCK_HOTEND_GAINS
from twin import BatchTwin, KlipperTwin, RunResult, Twin, make_plant
from twin.build import build_twin
from twin.scenario import parse_scenario
from twin.trace import Trace

README = Path(__file__).resolve().parents[2] / "README.md"
GAINS = PidGains(15.0, 0.875, 80.25)  # exact in float32, as M301 parses them


def readme_python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


@pytest.mark.parametrize("engine", ["Twin", "KlipperTwin"])
def test_readme_example_runs(engine, tmp_path, monkeypatch, capsys):
    """The README's Python block, executed as written (in a scratch directory for its plot), and on Klipper
    with the one name the README says to change."""
    blocks = readme_python_blocks()
    assert blocks, "README.md has no ```python block"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(re.sub(r"\bTwin\b", engine, blocks[0]), "README.md", "exec"), namespace)
    assert type(namespace["t"]).__name__ == engine
    result = namespace["result"]
    assert isinstance(result, RunResult)
    assert result.hotend.metrics().reached
    assert "overshoot_c" in capsys.readouterr().out
    assert list(tmp_path.glob("*.png"))


def test_public_names_are_exported():
    for name in twin.__all__:
        assert hasattr(twin, name), name


def test_heater_handles_set_target_and_gains():
    tw = Twin.create("pid", hotend="hotend", bed="bed")
    tw.hotend.target_c = 300  # clamped to HEATER_0_MAXTEMP - 15 as M104 does
    tw.bed.gains = GAINS
    assert tw.hotend.target_c == 260 and tw.bed.gains == GAINS
    with pytest.raises(ValueError, match="no PID gains"):
        Twin.create("bangbang").hotend.gains = GAINS


def test_marlin_and_klipper_twins_build_from_the_same_arguments():
    """Switching firmware is one name: Twin.create and KlipperTwin.create take the same arguments, put the
    same plants behind the same handles, start from the stock printer's gains, take new gains the same way
    (the README's notebook lines) and heat both heaters to their targets."""
    marlin, klipper = (cls.create("pid", hotend="hotend_cartridge", bed="bed", ambient_c=22.0)
                       for cls in (Twin, KlipperTwin))
    assert [(p.preset, p.ambient_c) for p in marlin.plants] == \
        [(c.plant.preset, c.plant.ambient_c) for c in klipper.channels.values()] == [("hotend_cartridge", 22.0),
                                                                                  ("bed", 22.0)]
    for engine in (marlin, klipper):
        assert engine.hotend.gains == pytest.approx(STOCK_HOTEND_GAINS)
        engine.hotend.target_c = 210
        engine.handles["bed"].target_c = 60
        engine.hotend.gains = GAINS
        assert engine.hotend.gains == pytest.approx(GAINS)
        result = engine.run(600)
        assert sorted(result.heaters) == ["bed", "hotend"]
        assert result.hotend.metrics().reached and result.heaters["bed"].metrics().reached
    assert "Kp=15, Ki=0.875, Kd=80.25" in repr(klipper.hotend)  # the heater runs the new gains


def test_klipper_twin_create_refuses_what_its_config_would():
    with pytest.raises(ValueError, match="control must be one of watermark, pid"):
        KlipperTwin.create("bangbang")
    watermark = KlipperTwin.create("watermark", kalico=True)
    assert type(watermark.heater("extruder")).__name__ == "KalicoHeater"
    with pytest.raises(ValueError, match="has no PID gains"):
        watermark.hotend.gains = GAINS


SERIAL = parse_scenario('duration_s = 86400\nname = "serial"\n', "serial")


def _recording(tw: Twin) -> Twin:
    tw.recording, tw.trace = True, Trace()
    tw.hotend.target_c = 210
    return tw


def test_injected_controller_equals_gains_set_through_m301():
    """A PidFixed instance injected into the twin runs bit for bit as the same gains sent to a
    serial printer as M301 (the injected twin is reset and run as the printer's was)."""
    printer = VirtualPrinter(lambda: build_twin(SERIAL, "pid", with_bed=False))
    printer.take_output()
    printer.receive(f"M301 P{GAINS.kp} I{GAINS.ki} D{GAINS.kd}\n".encode())
    printer.run_until_idle()
    assert printer.take_output() == b"ok\n"
    by_m301 = _recording(printer.twin)
    injected = build_twin(SERIAL, "pid", with_bed=False, controllers=[PidFixed(GAINS)])
    injected.reset_board()  # the printer's reset at connection
    injected.run_ticks(by_m301.tick - injected.tick)
    injected.origin_tick = by_m301.origin_tick
    injected = _recording(injected)
    assert injected.hotend.gains == by_m301.hotend.gains == GAINS
    a, b = by_m301.run(200), injected.run(200)
    assert len(a.t_s) > 1000
    assert np.array_equal(a.hotend.measured_c, b.hotend.measured_c)
    assert np.array_equal(a.hotend.duty, b.hotend.duty)


def test_controller_factory_is_called_at_each_reset():
    made = []

    def factory():
        made.append(PidFixed(GAINS))
        return made[-1]

    tw = Twin([make_plant("hotend")], "pid", controllers=[factory])
    tw.reset_board()
    assert len(made) == 2 and tw.hotend.controller is made[-1]


def test_batch_lanes_take_injected_controllers_equal_to_the_scalar_twin():
    gains = [GAINS, PidGains(22.2, 1.08, 114.0)]
    batch = BatchTwin(make_plant("hotend"), [PidFixed(g) for g in gains])
    batch.schedule(0.5, lambda b: b.set_target(210))
    lanes = batch.run(120)
    assert lanes.hotend.measured_c.shape[1] == 2 and lanes.hotend.lanes == 2
    for lane, g in enumerate(gains):
        tw = Twin([make_plant("hotend")], "pid")
        tw.hotend.gains = g  # what M301 does on the board
        tw.schedule(0.5, lambda t: setattr(t.hotend, "target_c", 210))
        single = tw.run(120)
        assert np.array_equal(single.hotend.measured_c, lanes.hotend.lane(lane).measured_c)
        assert np.array_equal(single.hotend.target_c, lanes.hotend.lane(lane).target_c)
    assert [m.reached for m in lanes.hotend.metrics()] == [True, True]


def test_batch_refuses_a_controller_it_cannot_vectorise():
    from firmware_port.fuzzy_pi import FuzzyPiFloat

    with pytest.raises(TypeError, match="lane 0"):
        BatchTwin(make_plant("hotend"), [FuzzyPiFloat()])


def test_one_result_type_for_the_klipper_twin():
    from twin.klipper_twin import KlipperTwin, bed_setup, extruder_setup

    kt = KlipperTwin([extruder_setup(), bed_setup()])
    kt.set_target("extruder", 200.0)
    kt.run_until(30.0)
    result = kt.result()
    assert isinstance(result, RunResult) and set(result.heaters) == {"hotend", "bed"}
    assert result.hotend.measured_c[-1] > 50 and len(result.bed.measured_c) == len(result.t_s)
    assert result.to_klipper_stats().startswith("Stats 1.")


def test_the_pid_publishes_its_terms_in_the_result():
    """One run record: the PID's P, I and D terms, one value per reading beside the trace; inside the band
    they sum to the output, which is twice the soft-PWM amount (duty x 127) within the law's rounding."""
    twin = Twin.create("pid", hotend="hotend_cartridge")
    twin.hotend.target_c = 210
    hotend = twin.run(200).hotend
    terms = hotend.signals
    assert sorted(terms) == ["d_counts", "i_counts", "p_counts"] and all(v.shape == hotend.t_s.shape for v in terms.values())
    inside = (np.abs(hotend.target_c - hotend.measured_c) < 10) & (hotend.t_s > 150)  # PID_FUNCTIONAL_RANGE
    total = terms["p_counts"] + terms["i_counts"] + terms["d_counts"]
    amount = np.clip(total[inside], 0, 255) / 2
    assert inside.sum() > 100 and np.max(np.abs(np.floor(amount) - np.round(hotend.duty[inside] * 127))) <= 1
