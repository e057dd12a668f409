"""The Kalico port on its own (no Kalico install needed): what its calibrations find on the twin's plants,
its config errors, the sections it writes, and the twin's flavour checks. test_referee.py holds it to
Kalico's code."""

from __future__ import annotations

import pytest

from firmware_port.kalico import KalicoHeaterConfig, MpcConfig, mpc_options, pid_options, section
from twin.klipper_twin import KlipperTwin, extruder_setup, kalico_extruder_setup
from twin.plants import (
    MPC_AMBIENT_XFER_W_K,
    MPC_BLOCK_HEAT_CAPACITY_J_K,
    MPC_HEATER_POWER_W,
    MPC_SENSOR_RESPONSIVENESS_PER_S,
    make_plant,
)


@pytest.mark.parametrize("preset", ["hotend", "hotend_stock"])
def test_kalicos_pid_calibrate_gives_a_lower_kp_later_than_klippers(preset):
    """Its symmetric relay with adapted power swings less than Klipper's full-power one, so its Ku, and Kp
    with it, is lower; converging takes more cycles than Klipper's 12 peaks."""
    kalico = KlipperTwin([kalico_extruder_setup(make_plant(preset))])
    klipper = KlipperTwin([extruder_setup(make_plant(preset))])
    ours, theirs = kalico.kalico_pid_calibrate("extruder", 210.0), klipper.pid_calibrate("extruder", 210.0)
    assert 0.6 * theirs.kp < ours.kp < theirs.kp
    assert kalico.time_s > klipper.time_s
    assert ours.powers[-1] < 1.0 and max(ours.powers[-4:]) - min(ours.powers[-4:]) <= 0.02
    assert (ours.kp, ours.ki, ours.kd) == tuple(float(ours.saved_options[k]) for k in ("pid_kp", "pid_ki", "pid_kd"))
    assert type(kalico.heater("extruder").control).__name__ == "ControlPID"  # the new gains installed


def mpc_calibration(**options):
    setup = kalico_extruder_setup(make_plant("hotend"), control="mpc", mpc=MpcConfig(MPC_HEATER_POWER_W))
    return KlipperTwin([setup]).mpc_calibrate("extruder", **options)


def test_mpc_calibrate_with_use_delta_finds_the_plants_constants():
    """The hotend preset is MPC's own model (block, sensor, ambient): USE_DELTA's asymptotic fit lands
    within 4 % of its C, R and A."""
    found = mpc_calibration(use_delta=True)
    for value, true in ((found.block_heat_capacity_j_k, MPC_BLOCK_HEAT_CAPACITY_J_K),
                        (found.sensor_responsiveness_per_s, MPC_SENSOR_RESPONSIVENESS_PER_S),
                        (found.ambient_transfer_w_k, MPC_AMBIENT_XFER_W_K)):
        assert value == pytest.approx(true, rel=0.04)


def test_mpc_calibrates_default_finds_the_sensor_slow():
    """The differential method's formula (time where the temperature belongs): well under half of R."""
    found = mpc_calibration()
    assert found.sensor_responsiveness_per_s < 0.5 * MPC_SENSOR_RESPONSIVENESS_PER_S
    assert found.config(MpcConfig(MPC_HEATER_POWER_W)).sensor_responsiveness_per_s == float(
        found.saved_options["sensor_responsiveness"])


@pytest.mark.parametrize(("options", "message"), [
    ({"control": "mpc"}, r"\[extruder\] control: mpc needs heater_power"),
    ({"control": "pid_v"}, r"\[extruder\] control: pid_v needs pid_kp, pid_ki and pid_kd"),
    ({"control": "pid", "pid_kp": 1.0, "pid_ki": 1.0, "pid_kd": 1.0, "pwm_resend": "2025-04"},
     r"\[extruder\] Kalico has one resend rule"),
    ({"control": "watermark", "lost_update_tolerance": -1}, r"\[extruder\] lost_update_tolerance must be"),
    ({"control": "dual_loop_pid"}, r"\[extruder\] control must be one of watermark, pid, pid_v, mpc"),
])
def test_a_bad_section_is_one_line_naming_the_option(options, message):
    with pytest.raises(ValueError, match=message):
        KalicoHeaterConfig("extruder", 0.0, 250.0, **options)


def test_a_bad_mpc_option_is_named():
    with pytest.raises(ValueError, match="mpc option heater_power must be a number above 0"):
        MpcConfig(0.0)
    with pytest.raises(ValueError, match="mpc option smoothing must be at most 1"):
        MpcConfig(40.0, smoothing=1.5)


def test_the_sections_a_user_pastes():
    assert section("extruder", pid_options(21.5271, 1.06, 108.98, target_c=210.0, tolerance=0.02)) == (
        "[extruder]\npid_version: 1\npid_target: 210.00\npid_tolerance: 0.0200\ncontrol: pid\n"
        "pid_kp: 21.527\npid_ki: 1.060\npid_kd: 108.980\n")
    mpc = MpcConfig(40.0, 19.41281, 0.0759730, 0.0645856, fan_ambient_transfer_w_k=(0.0646, 0.0826, 0.0956),
                    cooling_fan=True, smoothing=0.5)
    assert section("extruder", mpc_options(mpc)) == (
        "[extruder]\ncontrol: mpc\nheater_power: 40\nblock_heat_capacity: 19.4128\nsensor_responsiveness: "
        "0.0759730\nambient_transfer: 0.0645856\nfan_ambient_transfer: 0.0646, 0.0826, 0.0956\nsmoothing: 0.5\n"
        "cooling_fan: fan\n")
    with pytest.raises(ValueError, match="not all set"):
        mpc_options(MpcConfig(40.0))


def test_the_twin_runs_each_firmwares_calibration_on_its_own_heaters():
    with pytest.raises(ValueError, match="heater extruder runs Kalico: use kalico_pid_calibrate"):
        KlipperTwin([kalico_extruder_setup()]).pid_calibrate("extruder", 210.0)
    with pytest.raises(ValueError, match="heater extruder runs Klipper: give it a KalicoHeaterConfig"):
        KlipperTwin([extruder_setup()]).kalico_pid_calibrate("extruder", 210.0)
