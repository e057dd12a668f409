"""The lockstep engines: fast equals reference, determinism, faults tripping Marlin's protection."""

import numpy as np
import pytest

from firmware_port.marlin.pid import PidGains
from twin.batch import BatchTwin
from twin.build import build_twin
from twin.engine import Twin
from twin.linear import BLOCK
from twin.plants import make_plant
from twin.scenario import PRESETS, parse_scenario


class Recorder:
    """Logs every ADC conversion and every heater input the engines hand over."""

    def __init__(self, twin):
        self.samples = [[] for _ in twin.sensors]
        self.inputs = [[] for _ in twin.plants]
        for channel, (sensor, plant) in enumerate(zip(twin.sensors, twin.plants)):
            convert, advance = sensor.convert, plant.advance

            def logged_convert(sensor_c, ticks, _convert=convert, _log=self.samples[channel]):
                out = _convert(sensor_c, ticks)
                _log.extend(np.ravel(out).tolist())
                return out

            def logged_advance(u, _advance=advance, _log=self.inputs[channel]):
                _log.extend(np.asarray(u).tolist())
                _advance(u)

            sensor.convert, plant.advance = logged_convert, logged_advance


def run_both(scenario, firmware="pid", seconds=None, noise_lsb=0.5, setup=None):
    results = {}
    for engine in ("fast", "reference"):
        twin = build_twin(scenario, firmware, engine=engine, noise_lsb=noise_lsb)
        recorder = Recorder(twin)
        if setup:
            setup(twin)
        twin.run_until(seconds or scenario.duration_s)
        results[engine] = (twin, recorder)
    return results


def scenario(text):
    return parse_scenario(text, "test.toml")


HEAT_UP = scenario("""
duration_s = 40
seed = 3
[[setpoint]]
at_s = 0
heater = "hotend"
target_c = 200
[[setpoint]]
at_s = 0
heater = "bed"
target_c = 60
[[fan]]
at_s = 25
speed = 0.5
""")


@pytest.mark.parametrize("firmware", ["pid", "bangbang", "fuzzy_pi"])
def test_fast_engine_feeds_the_firmware_the_reference_samples_and_pins(firmware):
    """Linear plants: every ADC sample and every per-tick heater input identical, same trace."""
    results = run_both(HEAT_UP, firmware)
    (fast, rec_f), (ref, rec_r) = results["fast"], results["reference"]
    for channel in range(2):
        assert rec_f.samples[channel] == rec_r.samples[channel]
        assert rec_f.inputs[channel] == rec_r.inputs[channel]
    assert len(rec_f.inputs[0]) == fast.tick - fast.origin_tick  # one input per tick since boot
    rows_f, rows_r = fast.trace.rows, ref.trace.rows
    assert [r[:3] + r[5:8] + r[10:] for r in rows_f] == [r[:3] + r[5:8] + r[10:] for r in rows_r]
    true_f = np.array([r[3] for r in rows_f])
    true_r = np.array([r[3] for r in rows_r])
    assert np.max(np.abs(true_f - true_r)) < 1e-9


@pytest.mark.slow


def test_fast_engine_equals_reference_through_m303_with_dead_time_plant():
    """M303's 2 s deadlines split the fast engine's periods; a dead-time plant keeps its history."""
    sc = scenario("""
duration_s = 120
[plant.hotend]
preset = "seed001_fopdt"
""")

    def start(twin):
        twin.schedule(0.0, lambda tw: tw.board.start_autotune(0, 150, 3))

    results = run_both(sc, setup=start, noise_lsb=0.0)
    (fast, rec_f), (ref, rec_r) = results["fast"], results["reference"]
    assert fast.console.text == ref.console.text
    assert fast.console.text.startswith("PID Autotune start\n T:")
    assert rec_f.samples == rec_r.samples and rec_f.inputs == rec_r.inputs


@pytest.mark.slow


def test_nonlinear_plant_state_error_is_bounded():
    """With radiation on, the engines re-linearise at different instants: block temperatures
    stay within 0.05 C over a 200 C heat-and-hold (the bound holds for the 16.7 J/K MPC block; a
    lighter block heats faster between re-linearisations)."""
    sc = scenario("""
duration_s = 150
[plant.hotend]
preset = "hotend"
emissivity = 0.8
[[setpoint]]
at_s = 0
heater = "hotend"
target_c = 220
""")
    results = run_both(sc, noise_lsb=0.0)
    fast, ref = results["fast"][0], results["reference"][0]
    block_f = fast.result().hotend.block_c
    block_r = ref.result().hotend.block_c
    assert not fast.plants[0].linear
    assert np.max(np.abs(block_f - block_r)) < 0.05
    assert abs(block_f[-1] - 220) < 5


def test_same_seed_same_trace_bit_for_bit_and_other_seed_differs():
    csv = []
    for seed in (7, 7, 8):
        twin = build_twin(parse_scenario(f'duration_s = 30\nseed = {seed}\n[[setpoint]]\nat_s = 0\nheater = "hotend"\n'
                                         'target_c = 200\n', "s.toml"), noise_lsb=1.0)
        twin.run_until(30)
        csv.append(twin.result().to_csv())
    assert csv[0] == csv[1]
    assert csv[0] != csv[2]


def _trip_run(text, firmware="pid"):
    sc = scenario(text)
    twin = build_twin(sc, firmware)
    twin.run_until(sc.duration_s)
    return twin


def _assert_dead_after(twin, t_trip_s):
    hotend = twin.result().hotend
    after = hotend.t_s > t_trip_s + 0.2
    assert np.all(hotend.duty[after] == 0)
    assert np.all(hotend.target_c[after] == 0)
    assert twin.board.halted and not any(twin.board.pwm.pins)


def test_cartridge_falls_out_trips_thermal_runaway():
    twin = build_twin(PRESETS["cartridge_falls_out"])
    twin.run_until(PRESETS["cartridge_falls_out"].duration_s)
    text = [e for e in twin.trace.events if not e[1].startswith("scenario")]
    assert [line for _, line in text] == [
        "Error:Thermal Runaway, system stopped! Heater_ID: E0",
        "",
        "echo:THERMAL RUNAWAY",
        "Error:Printer halted. kill() called!",
    ]
    t_trip = text[0][0]
    assert 300 + 40 < t_trip < 300 + 80  # 40 s below target - 4 C after the heater went dead
    _assert_dead_after(twin, t_trip)


def test_thermistor_falls_out_trips_thermal_runaway_while_the_block_overheats():
    twin = build_twin(PRESETS["thermistor_falls_out"])
    twin.run_until(PRESETS["thermistor_falls_out"].duration_s)
    trips = [(t, line) for t, line in twin.trace.events if line.startswith("Error:Thermal Runaway")]
    assert trips and 340 < trips[0][0] < 380
    hotend = twin.result().hotend
    t, block = hotend.t_s, hotend.block_c
    assert block[np.searchsorted(t, trips[0][0])] > 230  # flat out on a false reading
    _assert_dead_after(twin, trips[0][0])


def test_heater_disconnected_from_the_start_fails_the_heating_watch():
    twin = _trip_run("""
duration_s = 60
[[fault]]
at_s = 0
heater = "hotend"
kind = "heater_disconnected"
[[setpoint]]
at_s = 1
heater = "hotend"
target_c = 200
""")
    trips = [(t, line) for t, line in twin.trace.events if line.startswith("Error:")]
    assert trips[0][1] == "Error:Heating failed, system stopped! Heater_ID: E0"
    assert 41 <= trips[0][0] < 41.5
    assert "echo:Heating Failed" in [line for _, line in twin.trace.events]


def test_open_thermistor_trips_mintemp_once_heating():
    twin = _trip_run("""
duration_s = 20
[[fault]]
at_s = 5
heater = "hotend"
kind = "thermistor_open"
[[setpoint]]
at_s = 10
heater = "hotend"
target_c = 200
""")
    trips = [(t, line) for t, line in twin.trace.events if line.startswith("Error:")]
    assert trips[0][1] == "Error:MINTEMP triggered, system stopped! Heater_ID: E0"
    assert 10 <= trips[0][0] < 10.2
    _assert_dead_after(twin, trips[0][0])


def test_shorted_thermistor_and_stuck_mosfet_trip_maxtemp():
    shorted = _trip_run("""
duration_s = 5
[[fault]]
at_s = 2
heater = "bed"
kind = "thermistor_short"
""")
    trips = [line for _, line in shorted.trace.events if line.startswith("Error:")]
    assert trips[0] == "Error:MAXTEMP triggered, system stopped! Heater_ID: bed"
    stuck = _trip_run("""
duration_s = 400
[[fault]]
at_s = 0
heater = "hotend"
kind = "heater_stuck_on"
""")
    trips = [(t, line) for t, line in stuck.trace.events if line.startswith("Error:")]
    assert trips[0][1] == "Error:MAXTEMP triggered, system stopped! Heater_ID: E0"
    # the MOSFET stays shorted: killing the board does not stop the heating
    assert stuck.plants[0].temps_c()[BLOCK] > 280


def test_batch_lanes_equal_scalar_twins():
    """Three gain sets as lanes of one BatchTwin, and as three scalar twins: same readings, same duty."""
    gains = [PidGains(22.2, 1.08, 114.0), PidGains(10.45, 1.15, 23.72), PidGains(40.0, 3.0, 60.0)]
    batch = BatchTwin(make_plant("hotend"), gains)
    batch.schedule(0.5, lambda b: b.set_target(210))
    batch.run_until(150)
    for lane, g in enumerate(gains):
        twin = Twin([make_plant("hotend")], "pid")
        twin.board.hotend.controller.set_gains(g)
        twin.schedule(0.5, lambda tw: tw.board.set_target(0, 210))
        twin.run_until(150)
        hotend = twin.result().hotend
        lanes = batch.result().hotend
        assert np.array_equal(hotend.measured_c, lanes.measured_c[:, lane])
        assert np.array_equal(hotend.duty, lanes.duty[:, lane])
        assert np.allclose(hotend.block_c, lanes.block_c[:, lane], atol=1e-9)
