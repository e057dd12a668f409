"""Kalico's PID_CALIBRATE (klippy/extras/pid_calibrate.py of Kalico): a symmetric relay whose power adapts.

The relay switches off above target + TUNE_PID_DELTA/2 and on below target - TUNE_PID_DELTA/2. Once the
temperature has crossed the target, each excursion beyond the band records a peak (its extreme, at the
mean time of the readings equal to it), stored when the temperature crosses back over the target. After
every second peak past the first the relay's power is rescaled so that the high and low peaks would sit
symmetrically about the target; the test ends when the last four powers agree within the tolerance (0.02
of the duty), or fails past TUNE_PID_MAX_PEAKS peaks. The gains are Ziegler-Nichols from the last three
cycles: Ku from their mean peak-to-peak swing and mean relay power, Tu from their mean period.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from firmware_port.kalico.heater import CONTROL_PID, CONTROL_PID_V, ControlVelocityPID, KalicoHeater
from firmware_port.kalico.printer import Printer, wait_for_temperature
from firmware_port.klipper.heater import CommandError, PwmEvent
from firmware_port.klipper.pid_calibrate import relay_ku, zn_from_relay

LOG = logging.getLogger(__name__)

TUNE_PID_DELTA = 5.0  # degC: the relay's band, centred on the target
TUNE_PID_TOL = 0.02  # TOLERANCE's default: the spread of the last TUNE_PID_SAMPLES + 1 powers
TUNE_PID_SAMPLES = 3  # cycles averaged for the gains
TUNE_PID_MAX_PEAKS = 60
PID_PROFILE_VERSION = 1
DEFAULT_PROFILE = "default"


class ControlAutoTune:
    """The relay control PID_CALIBRATE swaps into the heater. ``peaks`` are (time, temp); ``powers`` the
    relay's power per sample (duty); ``times`` the relay's switching times; ``data`` each reading's
    (read_time, temp, last sent pwm, target), what WRITE_FILE=1 writes."""

    def __init__(self, heater: KalicoHeater, target_c: float, tolerance: float, respond: Callable[[str], None]):
        self.heater = heater
        self.heater_max_power = heater.max_power
        self.respond = respond
        self.powers = [self.heater_max_power]
        self.times: list[float] = []
        self.target = target_c
        self.tolerance = tolerance
        self.temp_high = target_c + TUNE_PID_DELTA / 2.0
        self.temp_low = target_c - TUNE_PID_DELTA / 2.0
        self.heating = False
        self.peak = target_c  # the extreme of the current excursion (the target between excursions)
        self.peak_times: list[float] = []  # the readings equal to it
        self.peaks: list[tuple[float, float]] = []
        self.target_crossed = self.done = self.started = self.errored = False
        self.data: list[tuple[float, float, float, float]] = []

    def temperature_update(self, read_time: float, temp: float, target_temp: float) -> PwmEvent | None:
        if self.done:
            return None
        self.data.append((read_time, temp, self.heater.last_pwm_value, self.target))
        if not self.started and temp >= self.temp_low:
            return self.fail(read_time, "temperature is too high to start calibration")
        self.started = True
        if float(len(self.peaks)) > TUNE_PID_MAX_PEAKS:
            return self.fail(read_time, "calibration did not finish in time")
        if temp > self.target:
            self.target_crossed = True
        if self.target_crossed and self.track_peaks(read_time, temp):
            return self.finish(read_time)
        if self.heating and temp >= self.temp_high:
            self.heating = False
            self.times.append(read_time)
            self.heater.alter_target(self.temp_low)
        if not self.heating and temp <= self.temp_low:
            self.heating = True
            self.times.append(read_time)
            self.heater.alter_target(self.temp_high)
        return self.heater.set_pwm(read_time, self.powers[-1] if self.heating else 0.0)

    def track_peaks(self, read_time: float, temp: float) -> bool:
        """Record peaks; after every second peak past the first, a new sample: True if the powers converged,
        else the next power."""
        if temp > self.temp_high or temp < self.temp_low:
            self.check_peak(read_time, temp)
        if self.peak > self.temp_high and temp < self.target:
            self.store_peak()
        if self.peak < self.temp_low and temp > self.target:
            self.store_peak()
        peaks = float(len(self.peaks)) - 1.0
        if peaks % 2.0 != 0.0 or float(len(self.powers)) * 2.0 != peaks:
            return False
        self.log_info()
        if self.converged():
            return True
        self.set_power()
        return False

    def fail(self, read_time: float, message: str) -> PwmEvent | None:
        self.errored = True
        event = self.finish(read_time)
        self.respond(message)
        return event

    def check_peak(self, read_time: float, temp: float) -> None:
        if temp == self.peak:
            self.peak_times.append(read_time)
        if (temp > self.target and temp > self.peak) or (temp < self.target and temp < self.peak):
            self.peak = temp
            self.peak_times = [read_time]

    def store_peak(self) -> None:
        self.peaks.append((sum(self.peak_times) / float(len(self.peak_times)), self.peak))
        self.peak = self.target
        self.peak_times = []

    def sample_tolerance(self) -> float | None:
        """The spread of the last TUNE_PID_SAMPLES + 1 powers; None before there are that many."""
        if len(self.powers) < TUNE_PID_SAMPLES + 1:
            return None
        last = self.powers[-(TUNE_PID_SAMPLES + 1):]
        return max(last) - min(last)

    def converged(self) -> bool:
        tolerance = self.sample_tolerance()
        return tolerance is not None and tolerance <= self.tolerance

    def log_info(self) -> None:
        asymmetry = (self.peaks[-2][1] + self.peaks[-1][1]) / 2.0 - self.target
        tolerance = self.sample_tolerance()
        shown = "n/a" if tolerance is None else f"{tolerance:.4f}"
        self.respond(f"sample:{len(self.powers)} pwm:{self.powers[-1]:.4f} asymmetry:{asymmetry:.4f} "
                     f"tolerance:{shown}\n")

    def set_power(self) -> None:
        """The power that would centre the last low and high peaks on the target, capped at max_power."""
        peak_low, peak_high = self.peaks[-2][1], self.peaks[-1][1]
        mid = self.powers[-1] * ((self.target - peak_low) / (peak_high - peak_low))
        self.powers.append(self.heater_max_power if mid * 2.0 > self.heater_max_power else mid * 2.0)

    def finish(self, read_time: float) -> PwmEvent | None:
        event = self.heater.set_pwm(read_time, 0.0)
        self.heater.alter_target(0.0)
        self.done = True
        self.heating = False
        return event

    def check_busy(self, eventtime: float, smoothed_temp: float, target_temp: float) -> bool:
        if eventtime == 0.0 and smoothed_temp == 0.0 and target_temp == 0.0:  # the caller asks: failed?
            return self.errored
        return not self.done

    def relay(self) -> tuple[float, float, float, float]:
        """(Ku, Tu, theta, tau) of the last TUNE_PID_SAMPLES cycles; theta is the mean lag from a switch to
        its peak, tau Cohen-Coon's time constant (both only logged)."""
        temp_diff = time_diff = theta = 0.0
        for i in range(1, TUNE_PID_SAMPLES * 2, 2):
            temp_diff = temp_diff + self.peaks[-i][1] - self.peaks[-i - 1][1]
            time_diff = time_diff + self.peaks[-i][0] - self.peaks[-i - 2][0]
            theta = theta + self.peaks[-i][0] - self.times[-i]
        temp_diff = temp_diff / float(TUNE_PID_SAMPLES)
        tu = time_diff / float(TUNE_PID_SAMPLES)
        theta = theta / float(TUNE_PID_SAMPLES)
        last = self.powers[-TUNE_PID_SAMPLES:]
        ku = relay_ku(temp_diff, sum(last) / float(len(last)))
        wu = (2.0 * math.pi) / tu
        tau = math.tan(math.pi - theta * wu) / wu
        return ku, tu, theta, tau

    def calc_pid(self) -> tuple[float, float, float]:
        """Ziegler-Nichols from relay(): (pid_Kp, pid_Ki, pid_Kd) on the 0..255 scale."""
        ku, tu, theta, tau = self.relay()
        km = -math.sqrt(tau**2 * ((2.0 * math.pi) / tu) ** 2 + 1.0) / ku
        LOG.info("Ziegler-Nichols constants: Ku=%f Tu=%f", ku, tu)
        LOG.info("Cohen-Coon constants: Km=%f Theta=%f Tau=%f", km, theta, tau)
        return zn_from_relay(ku, tu)


@dataclass(frozen=True)
class PidCalibration:
    """What PID_CALIBRATE found: the gains as SAVE_CONFIG writes them (3 decimals) and as computed."""

    kp: float  # as saved, on the 0..255 scale
    ki: float
    kd: float
    computed: tuple[float, float, float]  # (Kp, Ki, Kd) before rounding
    ku: float
    tu_s: float
    peaks: list[tuple[float, float]]  # (time_s, temp_c)
    powers: list[float]  # the relay's power (duty) per sample
    saved_options: dict[str, str]  # in the heater's section ([extruder]) for the default profile


def pid_calibrate(printer: Printer, heater: KalicoHeater, target_c: float, tolerance: float = TUNE_PID_TOL,
                  heater_name: str | None = None, profile: str = DEFAULT_PROFILE) -> PidCalibration:
    """PID_CALIBRATE HEATER=<heater_name> TARGET=<target_c> [TOLERANCE=] [PROFILE=]: the relay test (a wait
    like M109's), then the new gains installed as a fresh pid (pid_v if that was the control) control.
    CommandError("pid_calibrate interrupted") if the test failed."""
    if not tolerance > 0.0:
        raise CommandError("Error on 'PID_CALIBRATE': TOLERANCE must be above 0.0")
    tune = ControlAutoTune(heater, target_c, tolerance, printer.respond_info)
    old_control = heater.set_control(tune)
    try:
        heater.set_target(target_c)
        wait_for_temperature(printer, heater)
    finally:
        heater.set_control(old_control, keep_target=False)
    if tune.check_busy(0.0, 0.0, 0.0):
        raise CommandError("pid_calibrate interrupted")
    ku, tu, _, _ = tune.relay()
    kp, ki, kd = tune.calc_pid()
    LOG.info("Autotune: final: Kp=%f Ki=%f Kd=%f, secondary=%s", kp, ki, kd, False)
    LOG.info("Autotune: final: Kp=%f Ki=%f Kd=%f", kp, ki, kd)
    name = heater.short_name if heater_name is None else heater_name
    printer.respond_info(
        f"PID parameters for {target_c:.2f}\xb0C: pid_Kp={kp:.3f} pid_Ki={ki:.3f} pid_Kd={kd:.3f}\n"
        f"Heater: {name}\nTolerance: {tolerance:.4f}\nProfile: {profile}\n"
        "The SAVE_CONFIG command will update the printer config file\nwith these parameters and restart the printer.")
    control = CONTROL_PID_V if isinstance(old_control, ControlVelocityPID) else CONTROL_PID
    heater.set_control(heater.pid_control(kp, ki, kd, control), keep_target=False)
    saved = {"pid_version": str(PID_PROFILE_VERSION), "pid_target": f"{target_c:.2f}",
             "pid_tolerance": f"{tolerance:.4f}", "control": control, "pid_kp": f"{kp:.3f}", "pid_ki": f"{ki:.3f}",
             "pid_kd": f"{kd:.3f}"}
    return PidCalibration(float(saved["pid_kp"]), float(saved["pid_ki"]), float(saved["pid_kd"]), (kp, ki, kd), ku, tu,
                          list(tune.peaks), list(tune.powers), saved)
