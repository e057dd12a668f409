"""A Z probe behind the twin MCU's pins (protocol/klipper_mcu/probe.py): a BLTouch reads its commands from
the servo pulses on its control pin and answers on its sensor pin as klippy's bltouch.py expects (pin up:
open; pin up + touch_mode: triggered; deployed: triggered where the nozzle is z_offset above the bed), and a
homing move onto a deployed probe stops the Z stepper there."""

from __future__ import annotations

import pytest

from protocol.klipper_mcu import motion
from protocol.klipper_mcu.board import TwinBoard
from protocol.klipper_mcu.dictionary import PWM_MAX, build_dictionary
from protocol.klipper_mcu.probe import PULSE_S, SIGNAL_PERIOD_S, Probe, command_of
from protocol.klipper_mcu.user_config import read_user_config
from tests.klipper_mcu.host import NO_SCENARIO, S, TestHost
from tests.klipper_mcu.test_motion import COMMS_TIMEOUT, ENDSTOP_HIT, REPORT_TICKS
from tests.klipper_mcu.test_user_config import ENDER3, write

BLTOUCH = ENDER3.replace("endstop_pin: ^PC4\nposition_endstop: 0.0\n", "endstop_pin: probe:z_virtual_endstop\n") + """
[bltouch]
sensor_pin: ^PC4
control_pin: PA4
z_offset: 2.5
"""
CYCLE_TICKS = round(SIGNAL_PERIOD_S * S)
Z_STEPS_TO_PROBE = 49000  # from mid-travel 125 mm at 0.0025 mm per step down to z_offset 2.5 mm


@pytest.mark.parametrize("name", sorted(PULSE_S))
def test_each_pulse_names_its_command_by_soft_or_8_bit_pwm(name):
    assert command_of(round(PULSE_S[name] * S) / CYCLE_TICKS) == name
    assert command_of(round(PULSE_S[name] / SIGNAL_PERIOD_S * PWM_MAX) / PWM_MAX) == name


def test_no_pulse_and_a_width_between_commands_are_no_command():
    assert command_of(0.0) is None and command_of(1.0) is None
    assert command_of((PULSE_S["pin_down"] + PULSE_S["touch_mode"]) / 2 / SIGNAL_PERIOD_S) is None


def bltouch_board(tmp_path) -> tuple[TwinBoard, Probe]:
    board = TwinBoard.for_config(read_user_config(write(tmp_path, BLTOUCH)), NO_SCENARIO)
    assert board.probe is not None and board.endstop("PC4") == (board.probe, 1)
    return board, board.probe


def send(board: TwinBoard, command: str) -> None:
    board.drive("PA4", 0, round(PULSE_S[command] * S), CYCLE_TICKS)
    board.drive("PA4", 0, 0, 1)  # klippy ends each command with a zero duty: no pulse, no change


def test_the_bltouch_state_machine(tmp_path):
    board, probe = bltouch_board(tmp_path)
    changes: list[str] = []
    probe.on_change = lambda: changes.append(probe.state)
    assert not probe.pressed(0)  # powered up with its pin up
    send(board, "touch_mode")
    assert probe.pressed(0)  # klippy's test_sensor: pin up + touch mode reads triggered
    send(board, "pin_up")
    assert not probe.pressed(0)
    send(board, "pin_down")
    assert not probe.pressed(0)  # deployed, the nozzle 125 mm up
    board.carriage("PB3").position = -Z_STEPS_TO_PROBE + 1  # one step above z_offset
    assert not probe.pressed(0)
    board.carriage("PB3").position = -Z_STEPS_TO_PROBE
    assert probe.pressed(0)
    send(board, "touch_mode")
    assert probe.pressed(0)  # deployed in touch mode: still pressed where it touches
    send(board, "set_5V_output_mode")
    send(board, "reset")
    assert not probe.pressed(0)
    assert changes == ["up_touch", "up", "down", "down_touch", "up"]
    assert probe.commands == ["touch_mode", "pin_up", "pin_down", "touch_mode", "set_5V_output_mode", "reset"]


def test_a_plain_probe_is_always_deployed(tmp_path):
    text = BLTOUCH.replace("[bltouch]\nsensor_pin: ^PC4\ncontrol_pin: PA4", "[probe]\npin: !PC4")
    board = TwinBoard.for_config(read_user_config(write(tmp_path, text)), NO_SCENARIO)
    probe, level = board.endstop("PC4")
    assert isinstance(probe, Probe) and level == 0 and not probe.pressed(0)
    board.carriage("PB3").position = -Z_STEPS_TO_PROBE
    assert probe.pressed(0)


def probe_host(tmp_path) -> TestHost:
    """klippy's Z homing on the probe: oid 0 stepper_z (PB3, dir PB2), 1 the probe's endstop (PC4), 2 the
    trsync, 3 the BLTouch's control pin (PA4) as a soft PWM of 20 ms cycles."""
    config = read_user_config(write(tmp_path, BLTOUCH))
    board = TwinBoard.for_config(config, NO_SCENARIO)
    host = TestHost(board, dictionary=build_dictionary("test", config.chip, families=(motion.FAMILY,)))
    step, direction, sensor, control = (config.chip.pin_number(p) for p in ("PB3", "PB2", "PC4", "PA4"))
    host.send(0, "allocate_oids count=4",
              f"config_stepper oid=0 step_pin={step} dir_pin={direction} invert_step=0 step_pulse_ticks=32",
              f"config_endstop oid=1 pin={sensor} pull_up=1", "config_trsync oid=2",
              f"config_digital_out oid=3 pin={control} value=0 default_value=0 max_duration=0",
              f"set_digital_out_pwm_cycle oid=3 cycle_ticks={CYCLE_TICKS}", "finalize_config crc=1")
    return host


def home_z(host: TestHost, start: int, deploy_at: int) -> None:
    """Home down towards z=0 from mid-travel at 100 clocks a step, the pin_down pulse at ``deploy_at``."""
    host.send(S // 2, f"queue_digital_out oid=3 clock={deploy_at} on_ticks={round(PULSE_S['pin_down'] * S)}",
              f"queue_digital_out oid=3 clock={deploy_at + CYCLE_TICKS * 5} on_ticks=0")
    host.send(start, f"trsync_start oid=2 report_clock={start} report_ticks={REPORT_TICKS} expire_reason={COMMS_TIMEOUT}",
              "stepper_stop_on_trigger oid=0 trsync_oid=2",
              f"trsync_set_timeout oid=2 clock={start + 100 * S}",
              f"endstop_home oid=1 clock={start} sample_ticks=240 sample_count=4 rest_ticks=400 pin_value=1 "
              f"trsync_oid=2 trigger_reason={ENDSTOP_HIT}",
              f"reset_step_clock oid=0 clock={start}", "set_next_step_dir oid=0 dir=0",
              "queue_step oid=0 interval=100 count=60000 add=0")


@pytest.mark.parametrize("deploy_after_start_s", [-0.25, 0.25])
def test_homing_onto_the_deployed_probe_stops_z_where_it_touches(tmp_path, deploy_after_start_s):
    """Deployed before the homing move or during it (the pulse is a change the endstop samples again on)."""
    host = probe_host(tmp_path)
    start = S
    home_z(host, start, start + round(deploy_after_start_s * S))
    host.run(start + 60000 * 100 + S)
    states = host.named("trsync_state")
    assert states[-1]["trigger_reason"] == ENDSTOP_HIT
    touch = start + Z_STEPS_TO_PROBE * 100  # its 49000th step: 400-clock samples from start meet it there
    assert states[-1]["clock"] == touch + 3 * 240
    host.send(start + 10 * S, "stepper_get_position oid=0")
    assert host.named("stepper_position") == [{"oid": 0, "pos": (-(Z_STEPS_TO_PROBE + 7)) & 0xFFFFFFFF}]


def test_homing_onto_a_raised_probe_never_triggers(tmp_path):
    host = probe_host(tmp_path)
    host.send(S, f"trsync_start oid=2 report_clock={S} report_ticks={REPORT_TICKS} expire_reason={COMMS_TIMEOUT}",
              "stepper_stop_on_trigger oid=0 trsync_oid=2", f"trsync_set_timeout oid=2 clock={S + 100 * S}",
              f"endstop_home oid=1 clock={S} sample_ticks=240 sample_count=4 rest_ticks=400 pin_value=1 "
              f"trsync_oid=2 trigger_reason={ENDSTOP_HIT}",
              f"reset_step_clock oid=0 clock={S}", "set_next_step_dir oid=0 dir=0",
              "queue_step oid=0 interval=100 count=60000 add=0")
    host.run(S + 60000 * 100 + S)
    assert all(s["can_trigger"] for s in host.named("trsync_state"))
