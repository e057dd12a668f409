"""Kalico's host-side heater control (the Klipper fork formerly Danger Klipper): its Heater's PWM rules,
pid_v, MPC and MPC_CALIBRATE, and its PID_CALIBRATE, in Python float as Kalico's host runs them. What Kalico
shares with Klipper bit for bit (ControlPID, the watermark, verify_heater) is the Klipper port's."""

from firmware_port.kalico.heater import (
    CONTROL_MPC,
    CONTROL_PID_V,
    CONTROLS_WITH_GAINS,
    ControlVelocityPID,
    KalicoHeater,
    KalicoHeaterConfig,
)
from firmware_port.kalico.mpc import ControlMPC, MpcConfig
from firmware_port.kalico.mpc_calibrate import MpcCalibrate, MpcCalibration, TuningControl
from firmware_port.kalico.pid_calibrate import ControlAutoTune, PidCalibration, pid_calibrate
from firmware_port.kalico.printer import Printer, wait_for_temperature
from firmware_port.kalico.save_config import mpc_options, pid_options, section

__all__ = [
    "CONTROL_MPC",
    "CONTROL_PID_V",
    "CONTROLS_WITH_GAINS",
    "ControlAutoTune",
    "ControlMPC",
    "ControlVelocityPID",
    "KalicoHeater",
    "KalicoHeaterConfig",
    "MpcCalibrate",
    "MpcCalibration",
    "MpcConfig",
    "PidCalibration",
    "Printer",
    "TuningControl",
    "mpc_options",
    "pid_calibrate",
    "pid_options",
    "section",
    "wait_for_temperature",
]
