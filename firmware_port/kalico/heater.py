"""Kalico's host-side heater (klippy/extras/heaters.py of Kalico, the Klipper fork formerly Danger Klipper).

Kalico's Heater is Klipper's with these differences, which ``KalicoHeater`` adds to ``KlipperHeater``:

- ``set_pwm`` suppresses changes below an absolute 0.05 (Klipper's rule before 2026-03) and resends an
  unchanged value ``lost_update_tolerance + 1`` reports before MAX_HEAT_TIME runs out (Klipper's 2025-08
  rule has 3 there, Kalico's default tolerance 2 gives the same);
- swapping the control keeps the target unless told not to (PID_CALIBRATE relies on it);
- setting a target asks the control whether it can run (MPC without its constants cannot);
- more controls: ``pid_v`` (velocity-form PID, here) and ``mpc`` (firmware_port/kalico/mpc.py).

Kalico's ControlPID and ControlBangBang compute exactly what Klipper's do (the same operations in the same
order, ``prev_temp`` starting at AMBIENT_TEMP for a control made from the config or by PID_CALIBRATE), so the
Klipper port's classes serve both; the referee (tests/firmware_port/kalico) checks it against Kalico's code.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

from firmware_port.klipper.heater import (
    AMBIENT_TEMP,
    CONTROL_PID,
    CONTROL_WATERMARK,
    CONTROLS as KLIPPER_CONTROLS,
    MIN_PWM_CHANGE_BEFORE_2026_03,
    PID_SETTLE_DELTA,
    PID_SETTLE_SLOPE,
    PWM_RESEND_2025_08,
    CommandError,
    Control,
    HeaterConfig,
    KlipperHeater,
    PwmEvent,
    duty_gains,
)
from firmware_port.kalico.mpc import ControlMPC, MpcConfig

CONTROL_PID_V = "pid_v"
CONTROL_MPC = "mpc"
CONTROLS_WITH_GAINS = (CONTROL_PID, CONTROL_PID_V)
LOST_UPDATE_TOLERANCE = 2  # heaters.py: lost_update_tolerance's default (reports), + 1 in the resend margin
HEATER_BED = "heater_bed"  # the section MPC_CALIBRATE gives a lower default target
@dataclass(frozen=True)
class KalicoHeaterConfig(HeaterConfig):
    """A Kalico heater section: Klipper's options with Kalico's defaults, plus pid_v, mpc and the resend margin."""

    CONTROLS: ClassVar[tuple[str, ...]] = (CONTROL_WATERMARK, CONTROL_PID, CONTROL_PID_V, CONTROL_MPC)
    min_pwm_change: str = MIN_PWM_CHANGE_BEFORE_2026_03  # Kalico's set_pwm: an absolute 0.05
    lost_update_tolerance: int = LOST_UPDATE_TOLERANCE
    mpc: MpcConfig | None = None  # required for control: mpc

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.control in CONTROLS_WITH_GAINS and None in (self.pid_kp, self.pid_ki, self.pid_kd):
            raise ValueError(f"[{self.name}] control: {self.control} needs pid_kp, pid_ki and pid_kd")
        if self.control == CONTROL_MPC and self.mpc is None:
            raise ValueError(f"[{self.name}] control: mpc needs heater_power (mpc=MpcConfig(...))")
        if self.pwm_resend != PWM_RESEND_2025_08:
            raise ValueError(f"[{self.name}] Kalico has one resend rule: pwm_resend {PWM_RESEND_2025_08!r}")
        if isinstance(self.lost_update_tolerance, bool) or not isinstance(self.lost_update_tolerance, int) \
                or self.lost_update_tolerance < 0:
            raise ValueError(f"[{self.name}] lost_update_tolerance must be an integer >= 0")


class KalicoHeater(KlipperHeater):
    """One heater as Kalico's host runs it (Kalico's heaters.Heater); see the module docstring."""

    config: KalicoHeaterConfig

    def __init__(self, config: KalicoHeaterConfig):
        super().__init__(config)
        self.lost_reports = float(config.lost_update_tolerance + 1)

    def new_control(self, config: HeaterConfig) -> Control:
        """Kalico's controls: Klipper's watermark and pid, and its own pid_v and mpc."""
        if config.control == CONTROL_PID_V:
            return ControlVelocityPID(self, config)
        if config.control == CONTROL_MPC:
            assert isinstance(config, KalicoHeaterConfig) and config.mpc is not None  # the config checks it
            return ControlMPC(self, config.mpc)
        return KLIPPER_CONTROLS[config.control](self, config)  # type: ignore[return-value]

    def set_target(self, temp_c: float) -> None:
        """Heater.set_temp: the range check, then (for a non-zero target) the control's own check."""
        if temp_c and (temp_c < self.min_temp or temp_c > self.max_temp):
            super().set_target(temp_c)  # raises Klipper's "Requested temperature ... out of range"
        check_valid = getattr(self.control, "check_valid", None)
        if temp_c and check_valid is not None:
            check_valid()
        self.target_temp = temp_c

    def set_control(self, control: Control, keep_target: bool = True) -> Control:
        """Swap the control object, keeping the target unless ``keep_target`` is False; returns the old one."""
        old_control = self.control
        self.control = control
        if not keep_target:
            self.target_temp = 0.0
        return old_control

    def pid_control(self, kp: float, ki: float, kd: float, control: str = CONTROL_PID) -> Control:
        """A fresh pid or pid_v control with these gains (0..255 scale), as PID_CALIBRATE installs it."""
        return self.new_control(dataclasses.replace(self.config, control=control, pid_kp=kp, pid_ki=ki, pid_kd=kd))


class ControlVelocityPID:
    """control: pid_v. PID in velocity form: each report adds Kp * -(slope) + Ki * dt * error +
    Kd * -(curvature) to the output, the slope (degC per report) and curvature (degC per report per s)
    each smoothed by a moving average over about smooth_time; the output is clipped to [0, max_power]
    and held at 0 without a target. The derivatives are of the temperature, not the error, so a new
    target makes no kick."""

    def __init__(self, heater: KlipperHeater, config: HeaterConfig):
        self.heater = heater
        self.heater_max_power = heater.max_power
        self.kp, self.ki, self.kd = duty_gains(config)
        self.smooth_time = heater.smooth_time
        self.temps = [AMBIENT_TEMP] * 3  # the last three readings, oldest first
        self.times = [0.0] * 3
        self.d1 = 0.0  # smoothed first difference, degC per report
        self.d2 = 0.0  # smoothed second difference over the last interval, degC per report per s
        self.pwm = 0.0

    def temperature_update(self, read_time: float, temp: float, target_temp: float) -> PwmEvent | None:
        self.temps = [self.temps[1], self.temps[2], temp]
        self.times = [self.times[1], self.times[2], read_time]
        dt = self.times[2] - self.times[1]
        d1 = self.temps[2] - self.temps[1]
        error = dt * (target_temp - self.temps[2])
        d2 = (self.temps[2] - 2.0 * self.temps[1] + self.temps[0]) / dt
        n = max(1.0, self.smooth_time / dt)
        self.d1 = ((n - 1.0) * self.d1 + d1) / n
        self.d2 = ((n - 1.0) * self.d2 + d2) / n
        p, i, d = self.kp * -self.d1, self.ki * error, self.kd * -self.d2
        self.pwm = max(0.0, min(self.heater_max_power, self.pwm + p + i + d))  # in this order: floats
        if target_temp == 0.0:
            self.pwm = 0.0
        return self.heater.set_pwm(read_time, self.pwm)

    def check_busy(self, eventtime: float, smoothed_temp: float, target_temp: float) -> bool:
        return abs(target_temp - smoothed_temp) > PID_SETTLE_DELTA or abs(self.d1) > PID_SETTLE_SLOPE


__all__ = ["CommandError", "ControlVelocityPID", "KalicoHeater", "KalicoHeaterConfig", "MpcConfig"]
