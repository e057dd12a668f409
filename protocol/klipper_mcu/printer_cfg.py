"""The printer.cfg sections that match the twin MCU: its serial port, the pins each heater hangs on,
the thermistor type and pull-up the board simulates, and a printer without motion to drive them."""

from __future__ import annotations

import re

from protocol.klipper_mcu.board import FAN_PIN, PULLUP_OHM, TwinBoard

CONFIG_END = "# end of the twin MCU's sections"  # the last line: a reader of the server's stdout stops there
# config/example-cartesian.cfg's [extruder] PID gains (a starting point: PID_CALIBRATE finds the plant's own)
EXAMPLE_PID = (22.2, 1.08, 114.0)


def printer_cfg(serial: str, board: TwinBoard) -> str:
    """The config text: [mcu], [printer] kinematics none, one section per heater, the part fan."""
    lines = ["# heater-twin Klipper MCU (twin-klipper-mcu): paste into printer.cfg, or use as it is",
             "[mcu]", f"serial: {serial}", "restart_method: command", "",
             "[printer]", "kinematics: none", "max_velocity: 1", "max_accel: 1", ""]
    for heater in board.heaters.values():
        wiring = heater.wiring
        lines += [f"[{wiring.section}]"]
        if wiring.heater == "hotend":
            lines += ["gcode_id: T0"]
        lines += [f"heater_pin: {wiring.heater_pin}", f"sensor_type: {board.sensor_type}",
                  f"sensor_pin: {wiring.sensor_pin}", f"pullup_resistor: {PULLUP_OHM:g}"]
        if wiring.heater == "hotend":
            lines += ["control: pid"] + [f"pid_{k}: {v:g}" for k, v in zip(("Kp", "Ki", "Kd"), EXAMPLE_PID)]
        else:
            lines += ["control: watermark"]
        lines += ["min_temp: 0", f"max_temp: {wiring.max_temp_c:g}", ""]
    if "hotend" in board.heaters:
        lines += ["[fan]", f"pin: {FAN_PIN}", ""]
    return "\n".join([*lines, CONFIG_END])


def user_printer_cfg(text: str, serial: str) -> str:
    """A user's printer.cfg with its [mcu] section's serial set to ``serial`` (added if it has none),
    ending in CONFIG_END; everything else as the user wrote it."""
    lines, out, section, done = text.splitlines(), [], "", False
    for line in lines:
        header = re.match(r"\s*\[([^\]]+)\]", line)
        if header:
            if section == "mcu" and not done:
                out.append(f"serial: {serial}")
                done = True
            section = header.group(1).strip()
        elif section == "mcu" and re.match(r"serial\s*[:=]", line) and not done:
            out.append(f"serial: {serial}")
            done = True
            continue
        out.append(line)
    if section == "mcu" and not done:
        out.append(f"serial: {serial}")
    return "\n".join([*out, CONFIG_END])
