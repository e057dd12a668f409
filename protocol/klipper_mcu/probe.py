"""A Z probe behind the MCU's pins: a BLTouch (klippy/extras/bltouch.py) or a plain [probe].

A BLTouch takes commands as servo pulses on its control pin, one every 20 ms, the pulse's width naming
the command (klippy's bltouch.py Commands: pin_down 0.650 ms, touch_mode 1.165, pin_up 1.475,
self_test 1.780, reset 2.190, and the output-mode ones). The twin reads the width from the pin's duty
as the MCU drives it (duty x 20 ms) and acts on a pulse at the clock it starts. Its sensor pin, as a
genuine BLTouch's (klippy's pin_up_reports_not_triggered and pin_up_touch_mode_reports_triggered
defaults): pin up reads open; pin up then touch_mode reads triggered (the self-check klippy's
test_sensor makes); a deployed pin (pin_down, or touch_mode after it) reads triggered where the
nozzle is at or below z_offset above the bed (the pin is z_offset longer than the nozzle); reset and
self_test leave the pin up. A plain [probe] is always deployed.
"""

from __future__ import annotations

from collections.abc import Callable

from protocol.klipper_mcu.axes import Carriage, Rail
from protocol.klipper_mcu.user_config import ProbePins

SIGNAL_PERIOD_S = 0.020  # bltouch.py: one servo pulse each 20 ms
PULSE_S = {"pin_down": 0.000650, "touch_mode": 0.001165, "pin_up": 0.001475, "self_test": 0.001780,
           "reset": 0.002190, "set_5V_output_mode": 0.001988, "set_OD_output_mode": 0.002091,
           "output_mode_store": 0.001884}
PULSE_TOLERANCE_S = 0.000045  # under half the closest two widths (0.104 ms apart); a hardware PWM's 8 bits give 39 us
UP, UP_TOUCH, DOWN, DOWN_TOUCH = "up", "up_touch", "down", "down_touch"
NEXT_STATE = {"pin_down": {UP: DOWN, UP_TOUCH: DOWN, DOWN: DOWN, DOWN_TOUCH: DOWN},
              "touch_mode": {UP: UP_TOUCH, UP_TOUCH: UP_TOUCH, DOWN: DOWN_TOUCH, DOWN_TOUCH: DOWN_TOUCH},
              "pin_up": dict.fromkeys((UP, UP_TOUCH, DOWN, DOWN_TOUCH), UP),
              "reset": dict.fromkeys((UP, UP_TOUCH, DOWN, DOWN_TOUCH), UP),
              "self_test": dict.fromkeys((UP, UP_TOUCH, DOWN, DOWN_TOUCH), UP)}


def command_of(duty: float) -> str | None:
    """The BLTouch command a servo pulse of ``duty`` (of the 20 ms period) names (None: no pulse, or no command)."""
    width_s = duty * SIGNAL_PERIOD_S
    name, pulse_s = min(PULSE_S.items(), key=lambda item: abs(item[1] - width_s))
    return name if duty > 0 and abs(pulse_s - width_s) <= PULSE_TOLERANCE_S else None


class Probe:
    """The probe's switch: pressed while deployed with the nozzle at or below z_offset (see the module's doc)."""

    def __init__(self, pins: ProbePins, carriage: Callable[[str], Carriage]):
        self.pins = pins
        self.z = Rail(pins.z, carriage) if pins.z is not None else None
        self.state = UP if pins.control_pin is not None else DOWN
        self.commands: list[str] = []  # what it was told, in order (for a reader of the twin's log)
        self.on_change: Callable[[], None] | None = None  # the MCU's: an endstop sampling it looks again

    def __repr__(self) -> str:
        return f"Probe({self.pins.sensor.name}, {self.state})"

    def command(self, duty: float) -> None:
        """A duty on the control pin from now on: a pulse that names a command acts on it."""
        name = command_of(duty)
        if name is None:
            return
        self.commands.append(name)
        new = NEXT_STATE.get(name, {}).get(self.state, self.state)
        if new != self.state:
            self.state = new
            if self.on_change is not None:
                self.on_change()

    def _touching(self, z_mm: float) -> bool:
        return z_mm <= self.pins.z_offset_mm

    def pressed(self, clock: int) -> bool:
        if self.state == UP_TOUCH:
            return True
        if self.state == UP or self.z is None:
            return False
        return self._touching(self.z.at_mm(clock))

    def pressed_from(self, clock: int) -> int | None:
        """The first clock from ``clock`` on at which it is pressed, as far as the queued moves go and while it
        stays in its state (a command calls ``on_change``)."""
        if self.state in (UP, UP_TOUCH) or self.z is None:
            return clock if self.pressed(clock) else None
        return self.z.first_clock(clock, self._touching)

    def moves_with(self, carriage: Carriage) -> bool:
        return self.z is not None and self.state in (DOWN, DOWN_TOUCH) and self.z.moves_with(carriage)
