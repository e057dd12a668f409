"""The contracts between the board and a heater controller, declared.

The board calls a controller on each fresh reading (every 0.16384 s) with the temperature in
celsius_q5 (int16 Q10.5, 1/32 degC), the target in whole degC and millis(); the controller
returns its output on Marlin's 0..255 scale (``PID_MAX``), which the board shifts into the 7-bit
soft PWM. A controller with ``check_interval_ms`` runs only that often on the bed (Marlin's
bang-bang bed gate). A ``Tunable`` controller also takes PID gains (M301/M304, M303 U1). A
``ReadsBoard`` controller also reads the rest of the firmware before each update, as Marlin's
MPC does (``BoardInputs``: its heater's soft-PWM amount, the part fan, the E stepper).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from firmware_port.marlin.pid import PidGains

OUTPUT_MAX = 255  # Marlin's PID_MAX: the top of every controller's output


@runtime_checkable
class Controller(Protocol):
    """What the board calls: ``update`` on a fresh reading, ``reset`` when control restarts."""

    @property
    def check_interval_ms(self) -> int | None:
        """None: run on every fresh reading; else at most this often (the bed's bang-bang gate)."""

    def reset(self) -> None: ...

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int: ...


@runtime_checkable
class Tunable(Controller, Protocol):
    """A controller with PID gains in user units (what M301/M304 set and M303 U1 applies)."""

    gains: PidGains

    def set_gains(self, gains: PidGains) -> None: ...


@dataclass(frozen=True)
class BoardInputs:
    """What Marlin's MPC reads in get_pid_output_hotend() besides the heater's reading."""

    amount: int  # the heater's soft_pwm_amount as it is now (the last output >> 1), 0..127
    fan_speed: int  # fan_speed[0], the part fan (M106), 0..255
    e_position_steps: int  # stepper.position(E_AXIS): int32 steps the E stepper has taken


@runtime_checkable
class ReadsBoard(Protocol):
    """A controller the board gives ``BoardInputs`` right before each ``update``."""

    def read_board(self, inputs: BoardInputs) -> None: ...


# A controller instance, or a factory the board calls for a fresh one at each reset.
ControllerSpec = Controller | Callable[[], Controller]


def is_tunable(controller: object) -> bool:
    return isinstance(controller, Tunable)
