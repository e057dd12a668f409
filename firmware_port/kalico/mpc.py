"""Kalico's MPC (klippy/extras/control_mpc.py ControlMPC): Marlin's model predictive control run on the host.

``ControlMPC`` keeps a model of the block, the sensor and the ambient: each report it predicts the block
from the last power, the losses to the ambient (the part fan's share interpolated in the fan's speed) and
to the filament fed, moves the sensor toward the block, then pulls both toward the reading by
``1 - (1 - smoothing)^dt``; while the power is steady or the model barely moves it nudges the ambient by at
least min_ambient_change * dt the same way. The power is the heat that would bring the block to the target
in target_reach_time plus the losses, clipped to max_power * heater_power, sent as a duty of heater_power.
Kept as Kalico has it: the steady-power test compares the power in W with 1.0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from firmware_port.klipper.heater import AMBIENT_TEMP, CommandError, KlipperHeater, PwmEvent

# control_mpc.py ControlMPC defaults (heaters.py ProfileManager._init_profile)
MPC_TARGET_REACH_TIME_S = 2.0
MPC_SMOOTHING = 0.83
MPC_MIN_AMBIENT_CHANGE_C = 1.0
MPC_STEADY_STATE_RATE_C_S = 0.5
MPC_FILAMENT_DIAMETER_MM = 1.75
MPC_FILAMENT_DENSITY_G_CM3 = 1.2
MPC_FILAMENT_HEAT_CAPACITY_J_G_K = 1.8
MPC_MAXIMUM_RETRACT_MM = 2.0
DEFAULT_DT_S = 0.1  # the time step of a first report or of one after a gap (< 0 or > 1 s)
SETTLE_C = 1.0  # check_busy: |target - smoothed| above this


@dataclass(frozen=True)
class MpcConfig:
    """The ``control: mpc`` options of a Kalico heater section (names as Kalico's, with units)."""

    heater_power_w: float  # heater_power: required
    block_heat_capacity_j_k: float | None = None  # None until MPC_CALIBRATE: the heater will not heat
    sensor_responsiveness_per_s: float | None = None
    ambient_transfer_w_k: float | None = None
    fan_ambient_transfer_w_k: tuple[float, ...] = ()  # at evenly spaced part-fan speeds 0..1
    cooling_fan: bool = False  # cooling_fan names the part fan: the ambient transfer follows its speed
    target_reach_time_s: float = MPC_TARGET_REACH_TIME_S
    smoothing: float = MPC_SMOOTHING
    min_ambient_change_c: float = MPC_MIN_AMBIENT_CHANGE_C
    steady_state_rate_c_s: float = MPC_STEADY_STATE_RATE_C_S
    filament_diameter_mm: float = MPC_FILAMENT_DIAMETER_MM
    filament_density_g_cm3: float = MPC_FILAMENT_DENSITY_G_CM3
    filament_heat_capacity_j_g_k: float = MPC_FILAMENT_HEAT_CAPACITY_J_G_K
    maximum_retract_mm: float = MPC_MAXIMUM_RETRACT_MM
    filament_temp_c: float | None = None  # filament_temperature_source: None is "ambient", a number is fixed

    def __post_init__(self) -> None:
        positive = {"heater_power": self.heater_power_w, "target_reach_time": self.target_reach_time_s,
                    "smoothing": self.smoothing, "min_ambient_change": self.min_ambient_change_c,
                    "steady_state_rate": self.steady_state_rate_c_s, "filament_diameter": self.filament_diameter_mm,
                    "filament_density": self.filament_density_g_cm3,
                    "filament_heat_capacity": self.filament_heat_capacity_j_g_k,
                    "maximum_retract": self.maximum_retract_mm, "block_heat_capacity": self.block_heat_capacity_j_k,
                    "sensor_responsiveness": self.sensor_responsiveness_per_s}
        for name, value in positive.items():
            if value is not None and not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"mpc option {name} must be a number above 0, got {value!r}")
        if self.smoothing > 1.0:
            raise ValueError(f"mpc option smoothing must be at most 1, got {self.smoothing!r}")
        if self.ambient_transfer_w_k is not None and not self.ambient_transfer_w_k >= 0.0:
            raise ValueError(f"mpc option ambient_transfer must be >= 0, got {self.ambient_transfer_w_k!r}")

    @property
    def calibrated(self) -> bool:
        """ControlMPC.is_valid: the three constants MPC_CALIBRATE measures are all set."""
        return None not in (self.block_heat_capacity_j_k, self.ambient_transfer_w_k, self.sensor_responsiveness_per_s)


    @property
    def filament_j_k_mm(self) -> float:
        """Heat capacity of a millimetre of filament (J/K): cross-section (mm^2 -> cm^3 per mm) x density x c."""
        radius = self.filament_diameter_mm / 2.0
        return radius * radius * math.pi / 1000.0 * self.filament_density_g_cm3 * self.filament_heat_capacity_j_g_k


class Extruder(Protocol):
    """The toolhead's extruder as ControlMPC asks it: its filament position (mm) at a print time."""

    def find_past_position(self, print_time: float) -> float: ...


class ControlMPC:
    """control: mpc (see the module docstring). State as Kalico names it, in degC: ``block_c``
    (state_block_temp), ``sensor_c``, ``ambient_c``; ``last_power`` in W."""

    def __init__(self, heater: KlipperHeater, config: MpcConfig, block_c: float = AMBIENT_TEMP):
        self.heater = heater
        self.config = config
        self.heater_max_power = heater.max_power * config.heater_power_w  # W
        self.filament_j_k_mm = config.filament_j_k_mm
        self.block_c = self.sensor_c = block_c
        self.ambient_c = AMBIENT_TEMP
        self.last_power = 0.0
        self.last_loss_ambient = 0.0
        self.last_loss_filament = 0.0
        self.last_temp_time = 0.0
        self.extruder: Extruder | None = None  # the toolhead's extruder when it drives this heater's nozzle
        self.fan_speed: Callable[[float], float] | None = None  # the part fan's speed (0..1) at a print time

    def check_valid(self) -> None:
        """Heater.set_temp asks this before a non-zero target: without its constants MPC cannot heat."""
        if self.config.calibrated:
            return
        name = self.heater.name
        raise CommandError(
            f"Cannot activate '{name}' as MPC control is not fully configured.\n\n"
            f"Run 'MPC_CALIBRATE' or ensure 'block_heat_capacity', 'sensor_responsiveness', and "
            f"'ambient_transfer' settings are defined for '{name}'.")

    def extrude_speeds(self, read_time: float, dt: float) -> tuple[float, float]:
        """Filament feed (mm/s) over the last dt and the next dt, each retraction capped at maximum_retract."""
        if self.extruder is None:
            return 0.0, 0.0
        retract = -self.config.maximum_retract_mm
        pos = self.extruder.find_past_position(read_time)
        pos_prev = self.extruder.find_past_position(read_time - dt)
        speed_prev = max(retract, pos - pos_prev) / dt
        pos_next = self.extruder.find_past_position(read_time + dt)
        return speed_prev, max(retract, pos_next - pos) / dt

    def ambient_transfer(self, read_time: float) -> float:
        """W/K to the ambient: ambient_transfer, or fan_ambient_transfer interpolated at the fan's speed."""
        table = self.config.fan_ambient_transfer_w_k
        if self.fan_speed is None or len(table) < 2:
            return self.config.ambient_transfer_w_k  # type: ignore[return-value]  # set: temperature_update checks
        fan_break = max(0.0, min(1.0, self.fan_speed(read_time))) * (len(table) - 1)
        below, above = table[math.floor(fan_break)], table[math.ceil(fan_break)]
        if below == above:
            return below
        frac = fan_break % 1.0
        return below * (1 - frac) + frac * above

    def temperature_update(self, read_time: float, temp: float, target_temp: float) -> PwmEvent | None:
        config = self.config
        if not config.calibrated:
            return self.heater.set_pwm(read_time, 0.0)
        dt = read_time - self.last_temp_time
        if self.last_temp_time == 0.0 or dt < 0.0 or dt > 1.0:
            dt = DEFAULT_DT_S
        speed_prev, speed_next = self.extrude_speeds(read_time, dt) if target_temp != 0.0 else (0.0, 0.0)
        ambient_transfer = self.ambient_transfer(read_time)
        capacity, responsiveness = config.block_heat_capacity_j_k, config.sensor_responsiveness_per_s
        assert capacity is not None and responsiveness is not None  # calibrated
        # predict: the last power, less the losses, over dt
        block_ambient_delta = self.block_c - self.ambient_c
        loss_ambient = block_ambient_delta * ambient_transfer
        loss_filament = block_ambient_delta * speed_prev * self.filament_j_k_mm
        expected_block_dt = (self.last_power - loss_ambient - loss_filament) * dt / capacity
        self.block_c += expected_block_dt
        self.sensor_c += (self.block_c - self.sensor_c) * responsiveness * dt
        # correct toward the reading
        adjustment = (temp - self.sensor_c) * (1.0 - (1.0 - config.smoothing) ** dt)
        self.block_c += adjustment
        self.sensor_c += adjustment
        if 0 < self.last_power < 1.0 or abs(expected_block_dt + adjustment) < config.steady_state_rate_c_s * dt:
            if adjustment > 0.0:
                self.ambient_c += max(adjustment, config.min_ambient_change_c * dt)
            else:
                self.ambient_c += min(adjustment, -config.min_ambient_change_c * dt)
        # output: reach the target in target_reach_time, plus the losses
        heating_power = (target_temp - self.block_c) * capacity / config.target_reach_time_s
        loss_ambient = (self.block_c - self.ambient_c) * ambient_transfer
        filament_c = self.ambient_c if config.filament_temp_c is None else config.filament_temp_c
        loss_filament = (self.block_c - filament_c) * speed_next * self.filament_j_k_mm
        power = 0.0
        if target_temp != 0.0:
            power = max(0.0, min(self.heater_max_power, heating_power + loss_ambient + loss_filament))
        self.last_power = power
        self.last_loss_ambient = loss_ambient
        self.last_loss_filament = loss_filament
        self.last_temp_time = read_time
        return self.heater.set_pwm(read_time, power / config.heater_power_w)

    def check_busy(self, eventtime: float, smoothed_temp: float, target_temp: float) -> bool:
        return abs(target_temp - smoothed_temp) > SETTLE_C
