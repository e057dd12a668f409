"""Reproduce an M303 capture's printed Ku and Kp/Ki/Kd from the same cycle's printed d, min, max
and Tu, with Marlin's own float32 formulas (firmware_port/marlin/autotune.py: ultimate_gain,
pid_from_relay), allowing for the rounding of what was printed.

Rounding: Marlin (and Repetier) print these floats with 2 decimals, so each printed input stands
for an interval of +-0.005 around it. Every formula here is monotonic in each input (Ku falls
with max - min; Kp, Ki, Kd rise with Ku; Ki falls and Kd rises with Tu), so the exact value lies
between the formula's values at the corners of those intervals; the printed output, itself
rounded to 2 decimals, must lie within that range widened by +-0.005. Tu reaches the formulas as
whole milliseconds (t_low + t_high), so its interval is taken in whole ms.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from firmware_port.marlin.autotune import pid_from_relay, ultimate_gain
from tools.logs import M303Cycle, M303Log, REPETIER_POWER_MAX

PRINT_HALF_STEP = 0.005  # Marlin's SERIAL_ECHO of a float: 2 decimals; half a step either way
NO_OVERSHOOT = "No overshoot"


@dataclass(frozen=True)
class PrintedValue:
    """One printed number against the range its printed inputs allow."""

    line_no: int
    name: str  # "Ku", "Kp", "Ki" or "Kd"
    printed: float
    low: float
    high: float

    @property
    def reproduced(self) -> bool:
        return self.low - PRINT_HALF_STEP <= self.printed <= self.high + PRINT_HALF_STEP


def _ku_range(cycle: M303Cycle, full_swing: bool) -> tuple[float, float]:
    """Ku at the widest and narrowest swing the printed min and max allow. Repetier divides by the
    full swing (max - min) where Marlin divides by half of it: half Marlin's Ku."""
    assert cycle.d is not None and cycle.min_c is not None and cycle.max_c is not None
    scale = 0.5 if full_swing else 1.0
    values = [scale * float(ultimate_gain(cycle.d, cycle.min_c + lo, cycle.max_c + hi))
              for lo, hi in ((PRINT_HALF_STEP, -PRINT_HALF_STEP), (-PRINT_HALF_STEP, PRINT_HALF_STEP))]
    return min(values), max(values)


def _gain_ranges(ku: float, tu_s: float, no_overshoot: bool) -> dict[str, tuple[float, float]]:
    """Kp, Ki, Kd over the corners of printed Ku +- 0.005 and Tu +- 0.005 s (in whole ms)."""
    periods_ms = (math.ceil((tu_s - PRINT_HALF_STEP) * 1000.0), math.floor((tu_s + PRINT_HALF_STEP) * 1000.0))
    corners = [pid_from_relay(np.float32(ku + dk), period_ms, no_overshoot)[1:]
               for dk, period_ms in itertools.product((-PRINT_HALF_STEP, PRINT_HALF_STEP), periods_ms)]
    return {name: (float(min(c[i] for c in corners)), float(max(c[i] for c in corners)))
            for i, name in enumerate(("Kp", "Ki", "Kd"))}


def check_cycle(cycle: M303Cycle, full_swing: bool = False) -> list[PrintedValue]:
    """The printed Ku (and the gains, where the cycle printed them and its rule) against the ranges
    its printed d/min/max/Tu allow; empty for a cycle that printed no Ku."""
    if cycle.ku is None or cycle.d is None or cycle.min_c is None or cycle.max_c is None:
        return []
    out = [PrintedValue(cycle.line_no, "Ku", cycle.ku, *_ku_range(cycle, full_swing))]
    gains = {"Kp": cycle.kp, "Ki": cycle.ki, "Kd": cycle.kd}
    if cycle.tu_s and cycle.rule and all(v is not None for v in gains.values()):
        ranges = _gain_ranges(cycle.ku, cycle.tu_s, cycle.rule == NO_OVERSHOOT)
        out += [PrintedValue(cycle.line_no, name, float(value), *ranges[name])  # type: ignore[arg-type]
                for name, value in gains.items()]
    return out


def check_log(log: M303Log) -> list[PrintedValue]:
    """Every printed Ku and gain of a capture against its own printed inputs."""
    full_swing = log.power_max == REPETIER_POWER_MAX
    return [value for cycle in log.cycles for value in check_cycle(cycle, full_swing)]
