"""Kalico heater sections as a user pastes them into printer.cfg: the options PID_CALIBRATE and
MPC_CALIBRATE save (SAVE_CONFIG writes the same keys and values into its auto-save block)."""

from __future__ import annotations

from collections.abc import Mapping

from firmware_port.kalico.heater import CONTROL_MPC, CONTROL_PID, CONTROLS_WITH_GAINS
from firmware_port.kalico.mpc import MpcConfig
from firmware_port.kalico.pid_calibrate import PID_PROFILE_VERSION

# MpcConfig fields -> Kalico's option names, in the order the section lists them
MPC_OPTIONS = {
    "heater_power_w": "heater_power", "block_heat_capacity_j_k": "block_heat_capacity",
    "sensor_responsiveness_per_s": "sensor_responsiveness", "ambient_transfer_w_k": "ambient_transfer",
    "fan_ambient_transfer_w_k": "fan_ambient_transfer", "target_reach_time_s": "target_reach_time",
    "smoothing": "smoothing", "min_ambient_change_c": "min_ambient_change",
    "steady_state_rate_c_s": "steady_state_rate", "filament_diameter_mm": "filament_diameter",
    "filament_density_g_cm3": "filament_density", "filament_heat_capacity_j_g_k": "filament_heat_capacity",
    "maximum_retract_mm": "maximum_retract", "filament_temp_c": "filament_temperature_source",
}
PART_FAN = "fan"  # [fan]: the part-cooling fan's section, what cooling_fan names
MEASURED = ("block_heat_capacity_j_k", "sensor_responsiveness_per_s", "ambient_transfer_w_k")  # saved as %#.6g


def section(name: str, options: Mapping[str, str]) -> str:
    """``[name]`` and one ``key: value`` line per option."""
    return "\n".join([f"[{name}]", *(f"{key}: {value}" for key, value in options.items())]) + "\n"


def pid_options(kp: float, ki: float, kd: float, control: str = CONTROL_PID, target_c: float | None = None,
                tolerance: float | None = None) -> dict[str, str]:
    """A pid or pid_v section's options as Kalico's PID profile saves them (gains on the 0..255 scale)."""
    if control not in CONTROLS_WITH_GAINS:
        raise ValueError(f"control must be one of {', '.join(CONTROLS_WITH_GAINS)}, not {control!r}")
    options = {"pid_version": str(PID_PROFILE_VERSION)}
    if target_c is not None:
        options["pid_target"] = f"{target_c:.2f}"
    if tolerance is not None:
        options["pid_tolerance"] = f"{tolerance:.4f}"
    return {**options, "control": control, "pid_kp": f"{kp:.3f}", "pid_ki": f"{ki:.3f}", "pid_kd": f"{kd:.3f}"}


def mpc_options(mpc: MpcConfig) -> dict[str, str]:
    """A control: mpc section's options: heater_power, the measured constants as MPC_CALIBRATE saves them,
    the fan's transfers if any, and every other option that differs from Kalico's default."""
    if not mpc.calibrated:
        raise ValueError("the MPC constants are not all set (run MPC_CALIBRATE)")
    defaults = MpcConfig(heater_power_w=mpc.heater_power_w)
    options = {"control": CONTROL_MPC}
    for field, key in MPC_OPTIONS.items():
        value = getattr(mpc, field)
        if field == "fan_ambient_transfer_w_k":
            if value:
                options[key] = ", ".join(f"{v:.6g}" for v in value)
        elif field in MEASURED:
            options[key] = f"{value:#.6g}"
        elif field == "heater_power_w" or value != getattr(defaults, field):
            options[key] = f"{value:g}"
    if mpc.cooling_fan:
        options["cooling_fan"] = PART_FAN
    return options

