"""A paper-compatible loop: a first-order plant with dead time under an unbounded controller.

What the seed papers simulate in MATLAB/Simulink: unity feedback, no heater saturation, no sensor,
no sampling beyond the solver's step. The plant ``K e^(-L s) / (T s + 1)`` is stepped exactly
under a zero-order hold of the controller's output (y[k+1] = a y[k] + (1 - a) K u[k - D] with
a = e^(-dt/T) and D = L/dt steps); the controller sees the error every step.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tools.ident.fit import Fopdt  # K e^(-L s) / (T s + 1), in the paper's units


@dataclass(frozen=True)
class IdealRun:
    """One step response of the ideal loop: times, plant output and controller output."""

    t_s: np.ndarray
    y: np.ndarray
    u: np.ndarray


def simulate(plant: Fopdt, controller: Callable[[float], float], target: float, duration_s: float,
             dt_s: float) -> IdealRun:
    """Step from y = 0 to ``target`` at t = 0; ``controller(error) -> input`` once per ``dt_s``.

    ``delay_s`` must be a whole number of steps, so the dead time is exact.
    """
    delay_steps = plant.delay_s / dt_s
    if not (dt_s > 0 and abs(delay_steps - round(delay_steps)) < 1e-9):
        raise ValueError(f"dt_s={dt_s!r} must divide the dead time {plant.delay_s} s")
    a = math.exp(-dt_s / plant.time_constant_s)
    pending = deque([0.0] * round(delay_steps))  # inputs still inside the dead time
    n = round(duration_s / dt_s)
    y = np.zeros(n + 1)
    u = np.zeros(n + 1)
    for k in range(n):
        u[k] = controller(target - y[k])
        pending.append(u[k])
        y[k + 1] = a * y[k] + (1.0 - a) * plant.gain_c * pending.popleft()
    u[n] = u[n - 1]
    return IdealRun(np.arange(n + 1) * dt_s, y, u)
