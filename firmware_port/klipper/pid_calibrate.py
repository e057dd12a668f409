"""PID_CALIBRATE (klippy/extras/pid_calibrate.py): a relay autotune and Klipper's Ziegler-Nichols rule.

The relay heats at max_power until the target, then stays off until TUNE_PID_DELTA below it, so
the oscillation runs between target - 5 and target + overshoot. Each relay switch stores the
extreme seen since the previous one; after 12 peaks (heater off) the gains come from the cycle
of median length.
"""

from __future__ import annotations

import logging
import math

from firmware_port.klipper.heater import PID_PARAM_BASE, CommandError, Control, KlipperHeater, PwmEvent

LOG = logging.getLogger(__name__)

TUNE_PID_DELTA = 5.0  # degC: the relay switches back on this far below the target
TUNE_PEAKS = 12  # ControlAutoTune.check_busy: done once the heater is off with this many peaks
FIRST_FINAL_POS = 4  # calc_final_pid considers the cycles ending at peaks[4:]
SAVE_CONFIG_LINES = (
    "The SAVE_CONFIG command will update the printer config file",
    "with these parameters and restart the printer.",
)


def relay_ku(peak_to_peak_c: float, max_power: float = 1.0) -> float:
    """Klipper's "Astrom-Hagglund" Ku = 4*max_power/(pi*a), a = half the peak-to-peak swing.

    It uses the full relay swing 0..max_power, so it is twice the textbook describing-function Ku."""
    amplitude = 0.5 * abs(peak_to_peak_c)
    return 4.0 * max_power / (math.pi * amplitude)


def zn_from_relay(ku: float, tu_s: float) -> tuple[float, float, float]:
    """Klipper's Ziegler-Nichols rule: (pid_Kp, pid_Ki, pid_Kd) on the 0..255 config scale."""
    ti = 0.5 * tu_s
    td = 0.125 * tu_s
    kp = 0.6 * ku * PID_PARAM_BASE
    return kp, kp / ti, kp * td


def invert_calibration(kp: float, ki: float, kd: float, max_power: float = 1.0) -> tuple[float, float, float, float]:
    """(Tu from 2Kp/Ki, Tu from 8Kd/Kp, Ku, relay peak-to-peak degC) of a PID_CALIBRATE result.

    The two Tu agree (to the saved rounding) only for gains that came from PID_CALIBRATE."""
    if kp <= 0.0 or ki <= 0.0:
        raise ValueError("Kp and Ki must be positive to invert a PID_CALIBRATE result")
    ku = kp / (0.6 * PID_PARAM_BASE)
    peak_to_peak_c = 8.0 * max_power / (math.pi * ku)
    return 2.0 * kp / ki, 8.0 * kd / kp, ku, peak_to_peak_c


class ControlAutoTune:
    """The relay control PID_CALIBRATE swaps into the heater, with its peak log."""

    def __init__(self, heater: KlipperHeater, target_c: float):
        self.heater = heater
        self.heater_max_power = heater.max_power
        self.calibrate_temp = target_c
        self.heating = False
        self.peak = 0.0  # the extreme since the last switch: a minimum while heating, else a maximum
        self.peak_time = 0.0
        self.peaks: list[tuple[float, float]] = []  # (temp, read_time); peaks[0] is a dummy (0, 0)
        self.last_pwm = 0.0
        self.pwm_samples: list[tuple[float, float]] = []  # (read_time + pwm_delay, requested value)
        self.temp_samples: list[tuple[float, float]] = []  # (read_time, temp)

    def __repr__(self) -> str:
        return f"ControlAutoTune({self.heater.short_name}, target={self.calibrate_temp:g}, peaks={len(self.peaks)})"

    def set_pwm(self, read_time: float, value: float) -> PwmEvent | None:
        """Record a changed request, then pass it through the heater's set_pwm."""
        if value != self.last_pwm:
            self.pwm_samples.append((read_time + self.heater.pwm_delay, value))
            self.last_pwm = value
        return self.heater.set_pwm(read_time, value)

    def temperature_update(self, read_time: float, temp: float, target_temp: float) -> PwmEvent | None:
        self.temp_samples.append((read_time, temp))
        if self.heating and temp >= target_temp:
            self.heating = False
            self.check_peaks()
            self.heater.alter_target(self.calibrate_temp - TUNE_PID_DELTA)
        elif not self.heating and temp <= target_temp:
            self.heating = True
            self.check_peaks()
            self.heater.alter_target(self.calibrate_temp)
        if self.heating:
            if temp < self.peak:
                self.peak, self.peak_time = temp, read_time
            return self.set_pwm(read_time, self.heater_max_power)
        if temp > self.peak:
            self.peak, self.peak_time = temp, read_time
        return self.set_pwm(read_time, 0.0)

    def check_busy(self, eventtime: float, smoothed_temp: float, target_temp: float) -> bool:
        return self.heating or len(self.peaks) < TUNE_PEAKS

    def check_peaks(self) -> None:
        """At a relay switch: store the extreme, restart tracking, log the gains of the last cycle."""
        self.peaks.append((self.peak, self.peak_time))
        self.peak = 9999999.0 if self.heating else -9999999.0
        if len(self.peaks) >= 4:
            self.calc_pid(len(self.peaks) - 1)

    def calc_pid(self, pos: int) -> tuple[float, float, float]:
        """Gains from the half swing peaks[pos-1] -> peaks[pos] and the period peaks[pos-2] -> peaks[pos]."""
        temp_diff = self.peaks[pos][0] - self.peaks[pos - 1][0]
        time_diff = self.peaks[pos][1] - self.peaks[pos - 2][1]
        ku = relay_ku(temp_diff, self.heater_max_power)
        kp, ki, kd = zn_from_relay(ku, time_diff)
        raw = (temp_diff, self.heater_max_power, ku, time_diff, kp, ki, kd)
        LOG.info("Autotune: raw=%f/%f Ku=%f Tu=%f  Kp=%f Ki=%f Kd=%f", *raw)
        return kp, ki, kd

    def calc_final_pid(self) -> tuple[float, float, float]:
        """calc_pid of the cycle of median length (the upper median, ties by position)."""
        cycle_times = [
            (self.peaks[pos][1] - self.peaks[pos - 2][1], pos) for pos in range(FIRST_FINAL_POS, len(self.peaks))
        ]
        midpoint_pos = sorted(cycle_times)[len(cycle_times) // 2][1]
        return self.calc_pid(midpoint_pos)

    def heattest_text(self) -> str:
        """What WRITE_FILE=1 writes to /tmp/heattest.txt: "pwm: <time> <value>" lines, then "<time> <temp>"."""
        pwm = [f"pwm: {time:.3f} {value:.3f}" for time, value in self.pwm_samples]
        out = [f"{time:.3f} {temp:.3f}" for time, temp in self.temp_samples]
        return "\n".join(pwm + out)


class PidCalibrate:
    """PID_CALIBRATE HEATER=<name> TARGET=<t>: swap in the relay, wait like M109, then report.

    The caller runs the wait: it feeds sensor reports to the heater and calls ``check_busy`` once a
    second (answering with M105-style lines, as Klipper does) until it is False, then ``finish()``.
    """

    def __init__(self, heater: KlipperHeater, target_c: float):
        self.heater = heater
        self.tune = ControlAutoTune(heater, target_c)
        self.old_control: Control = heater.set_control(self.tune)
        self.saved_options: dict[str, str] = {}  # what SAVE_CONFIG writes into the heater's section
        try:
            heater.set_target(target_c)
        except CommandError:
            heater.set_control(self.old_control)
            raise

    def __repr__(self) -> str:
        return f"PidCalibrate({self.heater.short_name}, target={self.tune.calibrate_temp:g}, " \
               f"peaks={len(self.tune.peaks)})"

    def check_busy(self, eventtime: float) -> bool:
        """True while the relay test is still running."""
        return self.heater.check_busy(eventtime)

    def finish(self) -> list[str]:
        """Restore the old control (target 0) and return the G-code reply lines (sent as "// ...").

        Raises CommandError("pid_calibrate interrupted") if the test did not complete."""
        self.heater.set_control(self.old_control)
        if self.tune.check_busy(0.0, 0.0, 0.0):
            raise CommandError("pid_calibrate interrupted")
        kp, ki, kd = self.tune.calc_final_pid()
        LOG.info("Autotune: final: Kp=%f Ki=%f Kd=%f", kp, ki, kd)
        self.saved_options = {"control": "pid", "pid_Kp": f"{kp:.3f}", "pid_Ki": f"{ki:.3f}", "pid_Kd": f"{kd:.3f}"}
        return [f"PID parameters: pid_Kp={kp:.3f} pid_Ki={ki:.3f} pid_Kd={kd:.3f}", *SAVE_CONFIG_LINES]
