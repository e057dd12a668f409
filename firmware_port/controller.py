"""The contracts between the board and a heater controller, declared.

The board calls a controller on each fresh reading (every 0.16384 s) with the temperature in
celsius_q5 (int16 Q10.5, 1/32 degC), the target in whole degC and millis(); the controller
returns its output on Marlin's 0..255 scale (``PID_MAX``), which the board shifts into the 7-bit
soft PWM. A controller with ``check_interval_ms`` runs only that often on the bed (Marlin's
bang-bang bed gate). A ``Tunable`` controller also takes PID gains (M301/M304, M303 U1). A
``ReadsBoard`` controller also reads the rest of the firmware before each update, as Marlin's
MPC does (``BoardInputs``: its heater's soft-PWM amount, the part fan, the E stepper). A
controller may publish its internals (the P, I and D terms of its last update) as ``signals``:
the engines record them beside the temperatures.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

OUTPUT_MAX = 255  # Marlin's PID_MAX: the top of every controller's output

# The gain domain in user units (-MAX..MAX) that the firmware's fixed-point PID documents and derives
# its bounds for (firmware_port/marlin/pid.py): what M301/M304 accept.
KP_MAX = 1000.0
KI_MAX = 100.0
KD_MAX = 5000.0


@dataclass(frozen=True)
class PidGains:
    """Gains in user units (what M301/M303/EEPROM use), each within -MAX..MAX: Marlin stores any float
    M301 sends, negative ones too. Kp counts/degC, Ki counts/(degC s), Kd counts s/degC.

    A negative zero is stored as 0.0: Marlin would divide by -0.0 into an integral ceiling of -inf
    and a NaN output; the twin keeps that one case sane.
    """

    kp: float
    ki: float
    kd: float

    def __post_init__(self) -> None:
        for name, top in (("kp", KP_MAX), ("ki", KI_MAX), ("kd", KD_MAX)):
            value = getattr(self, name)
            if not -top <= value <= top:
                raise ValueError(f"PID gain {name}={value} outside the supported range -{top:g}..{top:g}")
            object.__setattr__(self, name, value + 0.0)  # -0.0 + 0.0 == +0.0

    @classmethod
    def clamped(cls, kp: float, ki: float, kd: float) -> PidGains:
        """Gains forced into the supported ranges (M303 U1 on a degenerate oscillation)."""
        return cls(*(min(max(value, -top), top) for value, top in ((kp, KP_MAX), (ki, KI_MAX), (kd, KD_MAX))))


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


@runtime_checkable
class Observable(Protocol):
    """A controller that publishes internals of its last update: name -> value (e.g. PID terms in counts)."""

    def signals(self) -> dict[str, float]: ...


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
