"""Marlin's PID law in float32: the oracle for the fixed-point port.

avr-gcc's ``float`` and ``double`` are both IEEE single precision, so numpy.float32 with
Marlin's operation order reproduces ``PID_t::get_pid_output`` bit for bit, given the same
temperature. Temperatures arrive as celsius_q5 and are converted exactly (k/32 is a float32).
"""

from __future__ import annotations

import numpy as np

from firmware_port.marlin.constants import (
    ACTUAL_ADC_SAMPLES,
    OVERSAMPLENR,
    PID_FUNCTIONAL_RANGE_C,
    PID_K1,
    PID_MAX,
    TEMP_TIMER_FREQUENCY,
)
from firmware_port.marlin.pid import HOTEND_GAINS, PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND, PidGains
from firmware_port.params import ParamSpace, pid_params
from firmware_port.thermistor import TEMP_ONE

F32 = np.float32
# #define PID_dT ((OVERSAMPLENR * float(ACTUAL_ADC_SAMPLES)) / TEMP_TIMER_FREQUENCY)
PID_DT_F32 = F32(F32(OVERSAMPLENR * ACTUAL_ADC_SAMPLES) / F32(TEMP_TIMER_FREQUENCY))
PID_K2_F32 = F32(F32(1.0) - F32(float(PID_K1)))  # 1.0f - PID_K1
RANGE_F32 = F32(PID_FUNCTIONAL_RANGE_C)
MAX_POW_F32 = F32(PID_MAX)
ZERO_F32 = F32(0.0)


class PidFloat:
    """Marlin 2.1's ``PID_t`` with float32 state, same interface as ``PidFixed``."""

    check_interval_ms = None

    def __init__(self, gains: PidGains = HOTEND_GAINS, prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE):
        if prev_temp_mode not in (PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND):
            raise ValueError(f"prev_temp_mode must be {PREV_TEMP_EVERY_SAMPLE!r} or {PREV_TEMP_IN_BAND!r}")
        self.prev_temp_mode = prev_temp_mode
        self.set_gains(gains)
        self.prev_c = ZERO_F32  # temp_dState
        self.reset()

    def __repr__(self) -> str:
        return f"PidFloat({self.gains!r}, prev_temp_mode={str(self.prev_temp_mode)!r}, float32)"

    def set_gains(self, gains: PidGains) -> None:
        """Store as Marlin does: Kp, Ki*PID_dT (scalePID_i), Kd/PID_dT (scalePID_d)."""
        self.gains = gains
        self.kp = F32(gains.kp)
        # + 0.0: a negative Ki too small for float32 becomes +0.0 (PidGains' rule), not -0.0, whose
        # integral ceiling of -inf would make the output NaN
        self.ki = F32(F32(F32(gains.ki) * PID_DT_F32) + ZERO_F32)
        self.kd = F32(F32(gains.kd) / PID_DT_F32)
        self.reset()

    def reset(self) -> None:
        """Forget the integral and derivative (``pid_reset``)."""
        self.i_state = ZERO_F32
        self.d_term = ZERO_F32
        self.reset_pending = True

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """One step on a fresh reading; returns ``(int)output`` 0..255."""
        return int(self.update_f32(temp_q5, target_c))

    def update_f32(self, temp_q5: int, target_c: int) -> np.float32:
        """The law with its float32 output."""
        current = F32(F32(temp_q5) / F32(TEMP_ONE))
        target = F32(target_c)
        error = F32(target - current)
        if target_c == 0 or error < -RANGE_F32:
            self.reset_pending = True
            out = ZERO_F32
        elif error > RANGE_F32:
            self.reset_pending = True
            out = MAX_POW_F32
        else:
            if self.reset_pending:
                self.reset_pending = False
                self.i_state = ZERO_F32
                self.d_term = ZERO_F32
            with np.errstate(divide="ignore", over="ignore"):
                i_max = F32(MAX_POW_F32 / self.ki)  # +-inf when Ki is 0 or denormal, as on the AVR
            self.i_state = _constrain(F32(self.i_state + error), ZERO_F32, i_max)
            p_term = F32(self.kp * error)
            i_term = F32(self.ki * self.i_state)
            raw_d = F32(self.kd * F32(self.prev_c - current))
            self.d_term = F32(self.d_term + F32(PID_K2_F32 * F32(raw_d - self.d_term)))
            out = _constrain(F32(F32(F32(p_term + i_term) + self.d_term) + ZERO_F32), ZERO_F32, MAX_POW_F32)
            if self.prev_temp_mode == PREV_TEMP_IN_BAND:
                self.prev_c = current
        if self.prev_temp_mode == PREV_TEMP_EVERY_SAMPLE:
            self.prev_c = current
        return F32(out)


def pid_float_space(default: PidGains = HOTEND_GAINS) -> ParamSpace:
    """Marlin's float32 PID as a tunable family: Kp, Ki, Kd in M301 units."""
    return ParamSpace("pid_float", pid_params(default), lambda kp, ki, kd: PidFloat(PidGains(kp, ki, kd)), pid=True,
                      autotune="M303")


def _constrain(x: np.float32, low: np.float32, high: np.float32) -> np.float32:
    """Marlin's constrain(): the low bound is tested first, so a high bound below it (a negative
    Ki's integral ceiling) is what any value at or above the low bound becomes."""
    return low if x < low else high if x > high else x
