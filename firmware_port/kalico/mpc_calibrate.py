"""Kalico's MPC_CALIBRATE (klippy/extras/control_mpc.py MpcCalibrate): wait for the heater to settle (the
ambient), heat at full power to the target logging every reading, fit the heat-up's asymptote from three
equally spaced readings (the block's heat capacity from the fastest rise, or with USE_DELTA from the
asymptote), hold the rounded final block temperature under MPC with the first constants until it crosses
the target five times, and take the ambient transfer from the mean power over the last seconds (per
part-fan speed when the section names a fan).

Kept as Kalico has them: the differential sensor responsiveness puts the fastest rise's time where its
temperature belongs (rate / (rate t + ambient - t)) and the "fastest" rise is the first faster than the
previous best's time, which is why the default calibration finds the sensor slower than it is.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from firmware_port.kalico.heater import HEATER_BED, KalicoHeater
from firmware_port.kalico.mpc import ControlMPC, MpcConfig
from firmware_port.kalico.printer import Printer
from firmware_port.klipper.heater import CommandError, KlipperHeater, PwmEvent

LOG = logging.getLogger(__name__)

# MPC_CALIBRATE's defaults and constants (MpcCalibrate.run and its helpers)
CALIBRATE_TARGET_C = 200.0
CALIBRATE_TARGET_BED_C = 90.0  # for the section named heater_bed
CALIBRATE_MIN_TARGET_C = 60.0
AMBIENT_MAX_MEASURE_TIME_S = 20.0
AMBIENT_MEASURE_SAMPLE_TIME_S = 5.0
FAN_BREAKPOINTS = 3
AMBIENT_SETTLE_RATE_C_S = 0.01  # await_ambient: settled below this rate over the last 10 s
SETTLE_WINDOW_S = 10.0
SETTLE_MIN_SPAN_S = 8.0
STABLE_BAND_C = 0.015  # wait_stable: a crossing is this far past the target
STABLE_ON_TARGET_C = 0.1  # ... or this close for STABLE_ON_TARGET_CHECKS checks in a row
STABLE_ON_TARGET_CHECKS = 150
STABLE_MIN_TIME_S = 30.0
STABLE_INTERVAL_S = 0.2  # wait_stable polls five times a second
TRANSFER_CYCLES = 5
FAN_CYCLES = 3


class TuningControl:
    """MPC_CALIBRATE's control: a fixed output, every reading logged while ``logging``."""

    def __init__(self, heater: KlipperHeater):
        self.heater = heater
        self.value = 0.0
        self.target_c: float | None = None
        self.log: list[tuple[float, float]] = []  # (read_time, temp)
        self.logging = False

    def __repr__(self) -> str:
        return f"TuningControl({self.heater.short_name}, value={self.value:g}, target={self.target_c}, " \
               f"logged={len(self.log)})"

    def temperature_update(self, read_time: float, temp: float, target_temp: float) -> PwmEvent | None:
        if self.logging:
            self.log.append((read_time, temp))
        return self.heater.set_pwm(read_time, self.value)

    def check_busy(self, eventtime: float, smoothed_temp: float, target_temp: float) -> bool:
        return self.value != 0.0 or self.target_c != 0

    def set_output(self, value: float, target_c: float) -> None:
        self.value = value
        self.target_c = target_c
        self.heater.set_target(target_c)


@dataclass(frozen=True)
class MpcCalibration:
    """What MPC_CALIBRATE measured and what SAVE_CONFIG would write."""

    block_heat_capacity_j_k: float
    sensor_responsiveness_per_s: float
    ambient_transfer_w_k: float
    fan_ambient_transfer_w_k: tuple[float, ...]
    saved_options: dict[str, str]  # the heater section's options as SAVE_CONFIG writes them
    first_pass: dict[str, float]
    second_pass: dict[str, Any]
    ambient_c: float

    def config(self, mpc: MpcConfig) -> MpcConfig:
        """``mpc`` with the constants as saved (6 significant digits): the section after SAVE_CONFIG."""
        saved = self.saved_options
        fans = tuple(float(v) for v in saved["fan_ambient_transfer"].split(",") if v.strip())
        return dataclasses.replace(mpc, block_heat_capacity_j_k=float(saved["block_heat_capacity"]),
                                   sensor_responsiveness_per_s=float(saved["sensor_responsiveness"]),
                                   ambient_transfer_w_k=float(saved["ambient_transfer"]), fan_ambient_transfer_w_k=fans)


def fastest_rate(samples: Sequence[tuple[float, float]]) -> tuple[float, float, float]:
    """(time since the first sample, temperature, rate) of the heat-up's "fastest" two-interval rise: as
    Kalico's, a rate replaces the best when it exceeds the best's *time*, so this is the first rise faster
    than the time at which the one before it was found."""
    best = (-1.0, 0.0, 0.0)
    base_t = samples[0][0]
    for idx in range(2, len(samples)):
        rate = (samples[idx][1] - samples[idx - 2][1]) / (samples[idx][0] - samples[idx - 2][0])
        if rate > best[0]:
            best = (samples[idx - 1][0] - base_t, samples[idx - 1][1], rate)
    return best


def first_pass(all_samples: Sequence[tuple[float, float]], heater_power_w: float, ambient_c: float,
               threshold_c: float, use_delta: bool) -> dict[str, float]:
    """process_first_pass: the heat-up's asymptote from three equally spaced readings of its last stretch
    above threshold_c, the ambient transfer from it, and the block capacity and sensor responsiveness."""
    best_lower: int | None = None
    for idx, (_, temp) in enumerate(all_samples):
        if temp > threshold_c and best_lower is None:
            best_lower = idx
        elif temp < threshold_c:
            best_lower = None
    if best_lower is None:
        raise CommandError(f"the heat-up never rose above the threshold {threshold_c:.1f}")
    t1_time = all_samples[best_lower][0] - all_samples[0][0]
    samples = all_samples[best_lower:]
    pitch = math.floor((len(samples) - 1) / 2)
    dt = samples[pitch][0] - samples[0][0]
    t1, t2, t3 = samples[0][1], samples[pitch][1], samples[2 * pitch][1]
    asymp_t = (t2 * t2 - t1 * t3) / (2.0 * t2 - t1 - t3)
    block_responsiveness = -math.log((t2 - asymp_t) / (t1 - asymp_t)) / dt
    ambient_transfer = heater_power_w / (asymp_t - ambient_c)
    block_heat_capacity = sensor_responsiveness = -1.0
    start_temp = all_samples[0][1]
    if use_delta:  # the asymptotic method
        block_heat_capacity = ambient_transfer / block_responsiveness
        sensor_responsiveness = block_responsiveness / (
            1.0 - (start_temp - asymp_t) * math.exp(-block_responsiveness * t1_time) / (t1 - asymp_t))
    if not use_delta or block_heat_capacity < 0 or sensor_responsiveness < 0:  # the differential method
        rise_time, _, rate = fastest_rate(samples)
        block_heat_capacity = heater_power_w / rate
        sensor_responsiveness = rate / (rate * rise_time + ambient_c - rise_time)  # Kalico's: time for temp
    heat_time = all_samples[-1][0] - all_samples[0][0]
    return {"post_block_temp": asymp_t + (start_temp - asymp_t) * math.exp(-block_responsiveness * heat_time),
            "post_sensor_temp": all_samples[-1][1], "block_responsiveness": block_responsiveness,
            "ambient_transfer": ambient_transfer, "block_heat_capacity": block_heat_capacity,
            "sensor_responsiveness": sensor_responsiveness, "asymp_temp": asymp_t, "t1": t1, "t1_time": t1_time,
            "t2": t2, "start_temp": start_temp, "dt": dt}


def second_pass(first: dict[str, float], target_c: float, base_power_w: float, fan_powers: Sequence[tuple[float, float]],
                ambient_c: float, heater_power_w: float) -> dict[str, Any]:
    """process_second_pass: the ambient transfer from the power held at target_c, and the block capacity and
    sensor responsiveness from the asymptote that transfer implies."""
    target_ambient_c = target_c - ambient_c
    ambient_transfer = base_power_w / target_ambient_c
    asymp_t = ambient_c + heater_power_w / ambient_transfer
    block_responsiveness = -math.log((first["t2"] - asymp_t) / (first["t1"] - asymp_t)) / first["dt"]
    return {"ambient_transfer": ambient_transfer, "block_responsiveness": block_responsiveness,
            "block_heat_capacity": ambient_transfer / block_responsiveness,
            "sensor_responsiveness": block_responsiveness / (
                1.0 - (first["start_temp"] - asymp_t) * math.exp(-block_responsiveness * first["t1_time"])
                / (first["t1"] - asymp_t)),
            "asymp_temp": asymp_t, "fan_ambient_transfer": [power / target_ambient_c for _, power in fan_powers]}


class MpcCalibrate:
    """MPC_CALIBRATE HEATER=<name> [TARGET=] [THRESHOLD=] [USE_DELTA=1] [AMBIENT_MAX_MEASURE_TIME=]
    [AMBIENT_MEASURE_SAMPLE_TIME=] [FAN_BREAKPOINTS=] on a heater whose control is mpc."""

    def __init__(self, printer: Printer, heater: KalicoHeater, target_c: float | None = None,
                 threshold_c: float | None = None, use_delta: bool = False,
                 ambient_max_measure_time_s: float = AMBIENT_MAX_MEASURE_TIME_S,
                 ambient_measure_sample_time_s: float = AMBIENT_MEASURE_SAMPLE_TIME_S,
                 fan_breakpoints: int = FAN_BREAKPOINTS):
        if not isinstance(heater.control, ControlMPC):
            raise CommandError(f"The value '{heater.name}' is not valid for HEATER")  # MPC_CALIBRATE's mux
        if target_c is None:
            target_c = CALIBRATE_TARGET_BED_C if heater.name == HEATER_BED else CALIBRATE_TARGET_C
        if target_c < CALIBRATE_MIN_TARGET_C:
            raise CommandError(f"Error on 'MPC_CALIBRATE': TARGET must have minimum of {CALIBRATE_MIN_TARGET_C}")
        if not ambient_max_measure_time_s > 0.0:
            raise CommandError("Error on 'MPC_CALIBRATE': AMBIENT_MAX_MEASURE_TIME must be above 0.0")
        if not ambient_measure_sample_time_s < ambient_max_measure_time_s:
            raise CommandError("Error on 'MPC_CALIBRATE': AMBIENT_MEASURE_SAMPLE_TIME must be below "
                               f"{ambient_max_measure_time_s}")
        if fan_breakpoints < 2:
            raise CommandError("Error on 'MPC_CALIBRATE': FAN_BREAKPOINTS must have minimum of 2")
        self.printer, self.heater, self.orig_control = printer, heater, heater.control
        self.target_c = target_c
        self.threshold_c = max(50.0, min(100, target_c - 100.0)) if threshold_c is None else threshold_c
        self.use_delta = use_delta
        self.max_measure_s, self.sample_s = ambient_max_measure_time_s, ambient_measure_sample_time_s
        self.fan_breakpoints = fan_breakpoints

    def __repr__(self) -> str:
        return f"MpcCalibrate({self.heater.short_name}, target={self.target_c:g}, threshold={self.threshold_c:g}, " \
               f"use_delta={self.use_delta})"

    def run(self) -> MpcCalibration:
        """The whole calibration; the heater's control is restored (target 0) whatever happens."""
        heater, orig = self.heater, self.orig_control
        control = TuningControl(heater)
        old_control = heater.set_control(control)  # Kalico's keeps the target
        try:
            ambient_c = self.await_ambient()
            samples = self.heatup_test(control)
            try:
                first = first_pass(samples, orig.heater_max_power, ambient_c, self.threshold_c, self.use_delta)
            except (ArithmeticError, ValueError) as exc:  # Kalico stops with an internal error here
                raise CommandError(f"the heat-up did not give an asymptote ({exc})") from None
            LOG.info("First pass: %s", first)
            mpc = dataclasses.replace(orig.config, block_heat_capacity_j_k=first["block_heat_capacity"],
                                      ambient_transfer_w_k=first["ambient_transfer"],
                                      sensor_responsiveness_per_s=first["sensor_responsiveness"])
            new_control = ControlMPC(heater, mpc, first["post_block_temp"])
            new_control.sensor_c, new_control.ambient_c = first["post_sensor_temp"], ambient_c
            new_control.fan_speed, new_control.extruder = orig.fan_speed, orig.extruder
            heater.set_control(new_control)
            target_c, base_power_w, fan_powers = self.transfer_test(first)
            second = second_pass(first, target_c, base_power_w, fan_powers, ambient_c, orig.heater_max_power)
            LOG.info("Second pass: %s", second)
            return self.report(first, second, ambient_c)
        except CommandError as exc:
            raise CommandError(f"MPC_CALIBRATE failed: {exc}") from None
        finally:
            heater.set_control(old_control)
            heater.alter_target(0.0)

    def report(self, first: dict[str, float], second: dict[str, Any], ambient_c: float) -> MpcCalibration:
        """The reply and the options SAVE_CONFIG writes (the capacity and responsiveness of the first pass
        unless USE_DELTA)."""
        source = second if self.use_delta else first
        capacity, responsiveness = source["block_heat_capacity"], source["sensor_responsiveness"]
        transfer, fans = second["ambient_transfer"], tuple(second["fan_ambient_transfer"])
        fan_text = ", ".join(f"{p:.6g}" for p in fans)
        self.printer.respond_info(
            f"Finished MPC calibration of heater '{self.heater.name}'\n"
            "Measured:\n "
            f"  block_heat_capacity={capacity:#.6g} [J/K]\n"
            f"  sensor_responsiveness={responsiveness:#.6g} [K/s/K]\n"
            f"  ambient_transfer={transfer:#.6g} [W/K]\n"
            f"  fan_ambient_transfer={fan_text} [W/K]\n")
        saved = {"control": "mpc", "block_heat_capacity": f"{capacity:#.6g}",
                 "sensor_responsiveness": f"{responsiveness:#.6g}", "ambient_transfer": f"{transfer:#.6g}",
                 "fan_ambient_transfer": fan_text}
        return MpcCalibration(capacity, responsiveness, transfer, fans, saved, first, second, ambient_c)

    def await_ambient(self) -> float:
        """Wait for the heater to settle (below AMBIENT_SETTLE_RATE_C_S over 10 s); its temperature then."""
        self.heater.alter_target(1.0)  # Kalico: "turn on fan to increase settling speed"
        self.printer.respond_info("Waiting for heater to settle at ambient temperature")
        samples: list[tuple[float, float]] = []

        def unsettled(eventtime: float) -> bool:
            samples.append((eventtime, self.heater.get_temp(eventtime)[0]))
            while samples[0][0] < eventtime - SETTLE_WINDOW_S:
                samples.pop(0)
            span_s = samples[-1][0] - samples[0][0]
            if span_s < SETTLE_MIN_SPAN_S:
                return True
            return not abs((samples[-1][1] - samples[0][1]) / span_s) < AMBIENT_SETTLE_RATE_C_S

        self.printer.wait_while(unsettled)
        self.heater.alter_target(0.0)
        return samples[-1][1]

    def heatup_test(self, control: TuningControl) -> list[tuple[float, float]]:
        """Full power until the (smoothed) temperature reaches the target; every reading meanwhile."""
        self.printer.respond_info(f"Performing heatup test, target is {self.target_c:.1f} degrees")
        control.set_output(self.heater.max_power, self.target_c)
        control.logging = True
        self.printer.wait_while(lambda eventtime: self.heater.get_temp(eventtime)[0] < self.target_c)
        control.logging = False
        self.heater.alter_target(0.0)
        log, control.log = control.log, []
        return log

    def transfer_test(self, first: dict[str, float]) -> tuple[float, float, list[tuple[float, float]]]:
        """Hold the rounded final block temperature under MPC: (that target, the mean power held without the
        fan, (speed, power) per fan breakpoint when the section names a fan)."""
        target_c = round(first["post_block_temp"])
        self.heater.set_target(target_c)
        self.printer.respond_info(f"Performing ambient transfer tests, target is {target_c:.1f} degrees")
        self.wait_stable(TRANSFER_CYCLES)
        fan_powers: list[tuple[float, float]] = []
        if not self.orig_control.config.cooling_fan:
            power_w = self.measure_power()
            self.printer.respond_info(f"Average stable power: {power_w} W")
            return target_c, power_w, fan_powers
        for idx in range(self.fan_breakpoints):
            speed = idx / (self.fan_breakpoints - 1)
            self.printer.set_part_fan(self.heater.short_name, speed)
            self.printer.respond_info("Waiting for temperature to stabilize")
            self.wait_stable(FAN_CYCLES)
            self.printer.respond_info(f"Temperature stable, measuring power usage with {speed * 100.0:.0f}% fan speed")
            power_w = self.measure_power()
            self.printer.respond_info(f"{speed * 100.0:.0f}% fan average power: {power_w:.2f} W")
            fan_powers.append((speed, power_w))
        self.printer.set_part_fan(self.heater.short_name, 0.0)
        return target_c, fan_powers[0][1], fan_powers

    def wait_stable(self, cycles: int) -> None:
        """Until the temperature has crossed above the target ``cycles`` times and 30 s have passed, or has
        stayed within 0.1 C of it for 150 checks (30 s) after the first crossing."""
        below_target, above_target, on_target = True, 0, 0
        start_s = self.printer.monotonic()

        def unstable(eventtime: float) -> bool:
            nonlocal below_target, above_target, on_target
            temp, target = self.heater.get_temp(eventtime)
            if below_target and temp > target + STABLE_BAND_C:
                above_target += 1
                below_target = False
            elif not below_target and temp < target - STABLE_BAND_C:
                below_target = True
            if above_target >= cycles and self.printer.monotonic() - start_s > STABLE_MIN_TIME_S:
                return False
            on_target = on_target + 1 if above_target > 0 and abs(target - temp) < STABLE_ON_TARGET_C else 0
            return on_target < STABLE_ON_TARGET_CHECKS

        self.printer.wait_while(unstable, STABLE_INTERVAL_S)

    def measure_power(self) -> float:
        """The mean MPC power (W) over the last sample time (and a check more) of max_measure_s of polls."""
        samples: list[tuple[float, float]] = []  # (dt, energy J)
        elapsed_s = 0.0
        last_s: float | None = None

        def measuring(eventtime: float) -> bool:
            nonlocal elapsed_s, last_s
            dt = eventtime - (last_s if last_s is not None else eventtime)
            last_s = eventtime
            samples.append((dt, self.heater.control.last_power * dt))  # type: ignore[attr-defined]
            elapsed_s += dt
            return elapsed_s < self.max_measure_s

        self.printer.wait_while(measuring)
        total_energy = total_time = 0.0
        for dt, energy in reversed(samples):
            total_energy += energy
            total_time += dt
            if total_time > self.sample_s:
                break
        return total_energy / total_time
