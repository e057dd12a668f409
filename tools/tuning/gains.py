"""PID gains with their scale explicit: the one gains type of the tuning layer.

Marlin (M301/M304, ``DEFAULT_Kp``...) and Klipper (``pid_Kp``...) print gains on the same scale:
output counts of 0..255 per degC, Ki per second, Kd in seconds (Marlin's ``PID_MAX`` = 255;
Klipper's klippy/extras/heaters.py divides its config gains by ``PID_PARAM_BASE`` = 255 to get a
0..1 duty). A model-based rule works in heater duty 0..1 per degC: ``Gains.from_duty`` and
``Gains.duty`` convert. Marlin stores Ki and Kd per control sample (scaled by ``PID_dT``), a scale
users never type: ``Gains.firmware`` hands the gains to the firmware's PID, which applies it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_port.klipper.heater import PID_PARAM_BASE
from firmware_port.marlin.pid import PidGains

COUNTS_PER_DUTY = PID_PARAM_BASE  # 255: Klipper's PID_PARAM_BASE, Marlin's PID_MAX
PASTE_DIGITS = 4  # significant digits in ready-to-paste settings (Marlin prints M301 with 2 decimals)


@dataclass(frozen=True)
class Gains:
    """Parallel-form PID gains on the 0..255 scale (Marlin M301 and Klipper pid_K* units).

    kp: counts per degC; ki: counts per degC per second; kd: counts per (degC/s).
    """

    kp: float
    ki: float
    kd: float

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f"gain {name}={value} must be finite and >= 0")

    # -- other scales ----------------------------------------------------------------------
    @classmethod
    def from_duty(cls, kp: float, ki: float, kd: float) -> Gains:
        """Gains of a model-scale controller (heater duty 0..1 per degC) on the 0..255 scale."""
        return cls(kp * COUNTS_PER_DUTY, ki * COUNTS_PER_DUTY, kd * COUNTS_PER_DUTY)

    @classmethod
    def from_ti_td(cls, kp: float, ti_s: float, td_s: float) -> Gains:
        """Standard (ISA) form Kp (1 + 1/(Ti s) + Td s) to parallel; ti_s = inf means no integral."""
        return cls(kp, 0.0 if math.isinf(ti_s) else kp / ti_s, kp * td_s)

    @property
    def duty(self) -> tuple[float, float, float]:
        """(kp, ki, kd) in heater duty 0..1 per degC: the scale of a plant model's input."""
        return (self.kp / COUNTS_PER_DUTY, self.ki / COUNTS_PER_DUTY, self.kd / COUNTS_PER_DUTY)

    @property
    def ti_s(self) -> float:
        """Integral time Kp/Ki (inf without integral action)."""
        return self.kp / self.ki if self.ki else math.inf

    @property
    def td_s(self) -> float:
        """Derivative time Kd/Kp."""
        return self.kd / self.kp if self.kp else 0.0

    def firmware(self) -> PidGains:
        """The firmware's gains (ValueError if outside the range the fixed-point PID supports)."""
        return PidGains(self.kp, self.ki, self.kd)

    # -- ready to paste ---------------------------------------------------------------------
    def _fmt(self, value: float) -> str:
        return f"{value:.{PASTE_DIGITS}g}"

    def marlin_command(self, bed: bool = False) -> str:
        """``M301 E0 P.. I.. D..`` (hotend) or ``M304 P.. I.. D..`` (bed); follow with M500."""
        head = "M304" if bed else "M301 E0"
        return f"{head} P{self._fmt(self.kp)} I{self._fmt(self.ki)} D{self._fmt(self.kd)}"

    def marlin_defines(self, bed: bool = False) -> str:
        """The Configuration.h block: ``#define DEFAULT_Kp ...`` (``DEFAULT_bedKp`` for the bed)."""
        prefix = "DEFAULT_bed" if bed else "DEFAULT_"
        return "\n".join(f"#define {prefix}K{name} {self._fmt(value)}"
                         for name, value in (("p", self.kp), ("i", self.ki), ("d", self.kd)))

    def klipper_section(self, heater: str = "extruder") -> str:
        """A printer.cfg section: ``[extruder]``, ``control: pid``, ``pid_Kp: ...``."""
        return "\n".join([f"[{heater}]", "control: pid", f"pid_Kp: {self._fmt(self.kp)}",
                          f"pid_Ki: {self._fmt(self.ki)}", f"pid_Kd: {self._fmt(self.kd)}"])

    def __str__(self) -> str:
        return f"Kp {self._fmt(self.kp)} Ki {self._fmt(self.ki)} Kd {self._fmt(self.kd)}"
