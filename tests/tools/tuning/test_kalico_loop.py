"""The kalico loop: Klipper's loop with Kalico's heater (a log's settings carried over, Kalico's PWM rules), its
PID on the lanes equal to Kalico scalar twins, Kalico's PID_CALIBRATE and MPC_CALIBRATE as the references a
tune beats, and Kalico's MPC as a family of its own, on that loop only."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from firmware_port.firmwares import KALICO_MPC, param_space
from firmware_port.kalico import KalicoHeaterConfig, MpcConfig
from firmware_port.klipper.heater import PWM_RESEND_BEFORE_2025_04
from tools.tuning.evaluate import (
    KLIPPER_MAX_TEMP_C,
    Problem,
    firmware_autotune,
    kalico_mpc_config,
    klipper_setup,
    make_problem_plant,
    preset_problem,
    run_chunk,
    run_scalars,
    simulate,
)
from tools.tuning.ensemble import plant_ensemble
from tools.tuning.objectives import heater_terms
from tools.tuning.tuner import tune
from tools.validation.compare import HeaterInfo
from twin.klipper_twin import DEFAULT_SENSOR, KlipperTwin, kalico_extruder_setup
from twin.plants import SPECS, make_plant
from twin.scenario import Event

TARGET_C = 200.0
# a log's heater (tools/validation/compare.py): max_power 0.6, where Kalico's absolute 0.05 threshold is not
# Klipper's; Klipper's resend of before 2025-04, not Kalico's
LOG_HEATER = HeaterInfo(22.2, 1.08, 114.0, 0.6, DEFAULT_SENSOR, "", 4700.0, 1.0, 0.1, 0.0, 280.0,
                        PWM_RESEND_BEFORE_2025_04)
GAINS = np.array([[22.2, 1.08, 114.0], [30.0, 2.0, 50.0]])


def _short(problem: Problem, duration_s: float = 300.0) -> Problem:
    """The problem's first duration_s, a part-fan kick at 200 s."""
    return replace(problem, scenario=replace(problem.scenario, duration_s=duration_s,
                                             events=(Event(200.0, "fan", None, 1.0),)))


def _logged(loop: str) -> Problem:
    return _short(replace(preset_problem("hotend_cartridge", TARGET_C, loop=loop), klipper=LOG_HEATER, noise_lsb=1.0))


def test_the_kalico_loop_runs_the_logs_heater_on_kalico():
    kalico, klipper = _logged("kalico"), _logged("klipper")
    setup = klipper_setup(kalico, make_problem_plant(kalico), GAINS[1])
    assert isinstance(setup.config, KalicoHeaterConfig) and not isinstance(klipper_setup(klipper, None).config,
                                                                            KalicoHeaterConfig)
    config = setup.config
    assert (config.max_power, config.max_temp_c, config.smooth_time_s) == (0.6, KLIPPER_MAX_TEMP_C, 1.0)
    assert (config.pid_kp, config.pid_ki, config.pid_kd) == (30.0, 2.0, 50.0) and config.control == "pid"
    assert setup.noise_lsb == 1.0 and setup.sensor == DEFAULT_SENSOR


@pytest.mark.slow  # 9.4 s of CPU
def test_kalico_loop_lanes_equal_kalico_scalar_twins_and_differ_from_klippers():
    problem = _logged("kalico")
    assert problem.batched
    batch, scalar = run_chunk(problem, GAINS), run_scalars(problem, GAINS)
    np.testing.assert_array_equal(batch.temp_c, scalar.temp_c)
    np.testing.assert_array_equal(batch.duty, scalar.duty)
    klipper = run_chunk(_logged("klipper"), GAINS)
    assert not np.array_equal(klipper.duty, batch.duty)  # Kalico's PWM rules, not the log's Klipper's


def test_kalicos_pid_calibrate_is_the_kalico_loops_autotune():
    """What the tuner takes as the reference is KlipperTwin.kalico_pid_calibrate on Kalico's example extruder,
    and not Klipper's PID_CALIBRATE."""
    problem = preset_problem("hotend", 210, loop="kalico")
    name, gains = firmware_autotune(problem)
    twin = KlipperTwin([kalico_extruder_setup(make_plant("hotend"), max_temp_c=KLIPPER_MAX_TEMP_C)])
    direct = twin.kalico_pid_calibrate("extruder", 210)
    assert name == "PID_CALIBRATE" and gains.tolist() == [direct.kp, direct.ki, direct.kd]
    assert not np.allclose(gains, firmware_autotune(replace(problem, loop="klipper"))[1], rtol=0.05)
    refs = {c.method: c.params for c in tune(_short(problem), method="rules").references}
    assert refs["PID_CALIBRATE"].tolist() == gains.tolist()


def test_mpc_calibrate_gives_kalico_mpc_the_constants_it_saves_and_they_hold():
    problem = preset_problem("hotend", 210, loop="kalico", controller=param_space(KALICO_MPC))
    assert not problem.batched  # Kalico's MPC has no lanes: one KlipperTwin per candidate
    name, params = firmware_autotune(problem)
    twin = KlipperTwin([kalico_extruder_setup(make_plant("hotend"), max_temp_c=KLIPPER_MAX_TEMP_C, control="mpc",
                                              mpc=MpcConfig(40.0, cooling_fan=True))])
    saved = twin.mpc_calibrate("extruder", target_c=210).saved_options
    fans = saved["fan_ambient_transfer"].split(", ")
    assert name == "MPC_CALIBRATE" and len(fans) == 3
    assert params.tolist() == [float(saved[k]) for k in ("block_heat_capacity", "sensor_responsiveness",
                                                           "ambient_transfer")] + [float(fans[-1])]
    assert kalico_mpc_config(problem, params) == MpcConfig(40.0, *params[:3], (params[2], params[3]), True)
    run = simulate(_short(problem, 400.0), [params])
    terms = heater_terms(run)
    assert not run.tripped[0] and terms.hold_error_c[0] < 1.0
    setup = klipper_setup(problem, make_problem_plant(problem), params)
    assert setup.config.control == "mpc" and setup.config.mpc == kalico_mpc_config(problem, params)


def test_every_member_keeps_the_nominal_heater_power():
    """heater_power is the printer's setting: a member whose plant is a transfer function (its input in the
    paper's unit, 2000 at full duty) runs Kalico's MPC with the nominal hotend's 40 W, and no part fan."""
    ensemble = plant_ensemble((("hotend", SPECS["hotend"], 25.0), ("fopdt", SPECS["seed001_fopdt"], 25.0)), 1.0)
    problem = replace(preset_problem("hotend", 210, loop="kalico", controller=param_space(KALICO_MPC)),
                      ensemble=ensemble)
    hotend, fopdt = problem.members()
    assert (hotend.heater_power_w, fopdt.heater_power_w, fopdt.input_full_scale) == (40.0, 40.0, 2000.0)
    params = param_space(KALICO_MPC).defaults
    assert kalico_mpc_config(fopdt, params) == MpcConfig(40.0, *params[:3])


def test_kalico_mpc_runs_on_the_kalico_loop_only():
    space = param_space(KALICO_MPC)
    for loop in ("marlin", "klipper", "ideal"):
        with pytest.raises(ValueError, match="kalico_mpc is Kalico's MPC: it runs on the kalico loop only"):
            preset_problem("hotend", 210, loop=loop, controller=space)
    with pytest.raises(ValueError, match="the kalico loop runs a PID or Kalico MPC: controller mpc runs on"):
        preset_problem("hotend", 210, loop="kalico", controller=param_space("mpc"))
    with pytest.raises(ValueError, match="kalico_mpc is Kalico's host control"):
        space.make(space.defaults)
    with pytest.raises(ValueError, match="kalico_mpc is a hotend controller"):
        param_space(KALICO_MPC, "bed")
    assert space.hold([19.412834, 0.0759734, 0.06814136, 0.1]).tolist() == [19.4128, 0.0759734, 0.0681414, 0.1]
