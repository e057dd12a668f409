"""verify_heater (klippy/extras/verify_heater.py): Klipper's host-side thermal runaway check.

Once a second on the smoothed temperature: below target - hysteresis the shortfall adds up into
an error; while approaching a new target every heating_gain degC gained within check_gain_time
clears it, otherwise an error of max_error shuts the printer down.
"""

from __future__ import annotations

import logging
import math

from firmware_port.klipper.heater import KlipperHeater

LOG = logging.getLogger(__name__)

CHECK_INTERVAL_S = 1.0  # check_event reschedules itself at eventtime + 1
CHECK_GAIN_TIME_S = 20.0  # default check_gain_time
CHECK_GAIN_TIME_BED_S = 60.0  # default for the section named exactly heater_bed
NEVER = math.inf  # reactor.NEVER
HINT_THERMAL = """
See the 'verify_heater' section in docs/Config_Reference.md
for the parameters that control this check.
"""


class HeaterFault(Exception):
    """verify_heater shut the printer down; the message is the shutdown message (with the hint)."""


class VerifyHeater:
    """[verify_heater <heater>] with Klipper's defaults."""

    def __init__(
        self,
        heater: KlipperHeater,
        hysteresis_c: float = 5.0,
        max_error: float = 120.0,
        heating_gain_c: float = 2.0,
        check_gain_time_s: float | None = None,
    ):
        self.heater = heater
        self.heater_name = heater.short_name
        self.hysteresis = hysteresis_c
        self.max_error = max_error  # degC * checks
        self.heating_gain = heating_gain_c
        if check_gain_time_s is None:
            check_gain_time_s = CHECK_GAIN_TIME_BED_S if self.heater_name == "heater_bed" else CHECK_GAIN_TIME_S
        self.check_gain_time = check_gain_time_s
        self.approaching_target = self.starting_approach = False
        self.last_target = self.goal_temp = self.error = 0.0
        self.goal_systime = NEVER
        LOG.info("Starting heater checks for %s", self.heater_name)

    def __repr__(self) -> str:
        return f"VerifyHeater({self.heater_name}, hysteresis={self.hysteresis:g}, max_error={self.max_error:g}, " \
               f"heating_gain={self.heating_gain:g}, check_gain_time={self.check_gain_time:g}, error={self.error:.4g})"

    def check_event(self, eventtime: float) -> float:
        """One check; returns the time of the next. Raises HeaterFault on a runaway."""
        temp, target = self.heater.get_temp(eventtime)
        if temp >= target - self.hysteresis or target <= 0.0:
            # Temperature near target - reset checks
            if self.approaching_target and target:
                LOG.info("Heater %s within range of %.3f", self.heater_name, target)
            self.approaching_target = self.starting_approach = False
            if temp <= target + self.hysteresis:
                self.error = 0.0
            self.last_target = target
            return eventtime + CHECK_INTERVAL_S
        self.error += (target - self.hysteresis) - temp
        if not self.approaching_target:
            if target != self.last_target:
                LOG.info("Heater %s approaching new target of %.3f", self.heater_name, target)
                self.approaching_target = self.starting_approach = True
                self.goal_temp = temp + self.heating_gain
                self.goal_systime = eventtime + self.check_gain_time
            elif self.error >= self.max_error:
                self.heater_fault()
        elif temp >= self.goal_temp:
            # Temperature approaching target - reset checks
            self.starting_approach = False
            self.error = 0.0
            self.goal_temp = temp + self.heating_gain
            self.goal_systime = eventtime + self.check_gain_time
        elif eventtime >= self.goal_systime:
            self.approaching_target = False
            LOG.info("Heater %s no longer approaching target %.3f", self.heater_name, target)
        elif self.starting_approach:
            self.goal_temp = min(self.goal_temp, temp + self.heating_gain)
        self.last_target = target
        return eventtime + CHECK_INTERVAL_S

    def heater_fault(self) -> None:
        """Log the error and shut down (the caller turns HeaterFault into the printer's shutdown)."""
        msg = f"Heater {self.heater_name} not heating at expected rate"
        LOG.error(msg)
        raise HeaterFault(msg + HINT_THERMAL)
