"""Marlin versions the port can behave as, with one spelling each (the default is 2.1)."""

from enum import StrEnum


class MarlinVersion(StrEnum):
    """A Marlin release line whose heater behaviour differs from its neighbours'."""

    V1_1 = "1.1"  # 1.1.x: M303's older loop and rules
    V2_0 = "2.0"  # 2.0.x: PID T_prev on every sample, heater_on counts a driven PID hotend
    V2_1 = "2.1"  # 2.1.x (default): PID T_prev only in band, LCD message echoed on kill


DEFAULT_VERSION = MarlinVersion.V2_1
