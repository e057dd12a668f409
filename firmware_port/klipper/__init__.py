"""Klipper's host-side heater control (klippy/extras/heaters.py, pid_calibrate.py, verify_heater.py)
in Python float, as the Klipper host runs it, for replaying and comparing with Klipper logs."""

from firmware_port.klipper.heater import (
    KLIPPER_COMMIT,
    KLIPPY_0_12,
    CommandError,
    ControlBangBang,
    ControlPID,
    HeaterConfig,
    KlipperHeater,
    PwmEvent,
)
from firmware_port.klipper.pid_calibrate import (
    ControlAutoTune,
    PidCalibrate,
    invert_calibration,
    relay_ku,
    zn_from_relay,
)
from firmware_port.klipper.verify_heater import HeaterFault, VerifyHeater

__all__ = [
    "KLIPPER_COMMIT",
    "KLIPPY_0_12",
    "CommandError",
    "ControlAutoTune",
    "ControlBangBang",
    "ControlPID",
    "HeaterConfig",
    "HeaterFault",
    "KlipperHeater",
    "PidCalibrate",
    "PwmEvent",
    "VerifyHeater",
    "invert_calibration",
    "relay_ku",
    "zn_from_relay",
]
