"""The idealised loop the papers simulate: a continuous-time parallel PID on the linear model with its
dead time, a set-point step, no firmware (no ADC, PWM, integer maths or output clamp unless asked).

The plant steps exactly (zero-order hold) at a small step, its dead time as whole steps; the PID
acts on the error at each step: integral by the rectangle rule, derivative by the backward
difference through an optional first-order filter (Simulink's PID block filters it with
N = 100 by default, a 0.01 s time constant). With steps far below the loop's time scales this is
the continuous loop the papers plot.

    run = step_response(model, (kp, ki, kd), duration_s=600)
    metrics = step_metrics(run.t_s, run.output, 1.0)     # twin.metrics
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from tools.tuning.models import LinearModel

STEP_S = 0.01  # default simulation step (the dead time is rounded to whole steps of at most this)
DIVERGED = 1e6  # |output| beyond this many set points: the loop is unstable, the run stops


class LoopRun(NamedTuple):
    """Times, the model's output (its own units, from 0), the controller's output, and whether it diverged."""

    t_s: np.ndarray
    output: np.ndarray
    control: np.ndarray
    diverged: bool


def closed_loop(model: LinearModel, controller: Callable[[float], float], setpoint: float = 1.0,
                duration_s: float = 600.0, step_s: float = STEP_S) -> LoopRun:
    """The loop from rest after a set-point step at t = 0, unity feedback: ``controller(error)``
    once per step_s, its output held (zero-order hold) through the model, whose dead time step_s
    must divide (whole steps: exact). Any controller: a PID (``step_response``), seed 001's fuzzy PID."""
    if duration_s <= 0 or step_s <= 0:
        raise ValueError("duration_s and step_s must be > 0")
    delay_steps = round(model.delay_s / step_s)
    if abs(model.delay_s / step_s - delay_steps) > 1e-9:
        raise ValueError(f"step_s={step_s!r} must divide the dead time {model.delay_s} s")
    n = len(model.b)
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n], aug[:n, n] = model.a, model.b
    import scipy.linalg
    disc = scipy.linalg.expm(aug * step_s)
    phi, gam = disc[:n, :n], disc[:n, n]
    steps = int(round(duration_s / step_s))
    y, u = np.zeros(steps + 1), np.zeros(steps + 1)
    buffer = np.zeros(delay_steps)
    x = np.zeros(n)
    diverged = False
    for k in range(steps + 1):
        y[k] = model.c @ x
        if abs(y[k]) > DIVERGED * max(abs(setpoint), 1.0):
            diverged = True
            y, u = y[: k + 1], u[: k + 1]
            break
        u[k] = applied = controller(setpoint - y[k])
        if delay_steps:
            applied, buffer[k % delay_steps] = buffer[k % delay_steps], u[k]
        x = phi @ x + gam * applied
    return LoopRun(step_s * np.arange(len(y)), y, u, diverged)


class Pid:
    """The papers' parallel PID as a controller for ``closed_loop``: integral by the rectangle rule,
    derivative by the backward difference through a first-order filter, output clipped to
    control_limits if given (no anti-windup: the papers' linear loop has none)."""

    def __init__(self, gains: tuple[float, float, float], step_s: float, derivative_filter_s: float = 0.0,
                 control_limits: tuple[float, float] | None = None):
        self.kp, self.ki, self.kd = gains
        self.step_s, self.filter_s, self.limits = step_s, derivative_filter_s, control_limits
        self.integral = self.derivative = 0.0
        self.previous_error = 0.0  # the loop at rest before the step: e = 0

    def __repr__(self) -> str:
        return f"Pid(kp={self.kp:g}, ki={self.ki:g}, kd={self.kd:g}, step_s={self.step_s:g}, " \
               f"derivative_filter_s={self.filter_s:g}, control_limits={self.limits})"

    def __call__(self, error: float) -> float:
        self.integral += self.ki * error * self.step_s
        self.derivative = (self.filter_s * self.derivative + self.kd * (error - self.previous_error)) \
            / (self.filter_s + self.step_s)
        self.previous_error = error
        u = self.kp * error + self.integral + self.derivative
        return u if self.limits is None else min(max(u, self.limits[0]), self.limits[1])


def step_response(model: LinearModel, gains: tuple[float, float, float], setpoint: float = 1.0,
                  duration_s: float = 600.0, step_s: float = STEP_S, derivative_filter_s: float = 0.0,
                  control_limits: tuple[float, float] | None = None) -> LoopRun:
    """The closed loop under ``Pid``: u = kp e + ki int e + kd de/dt (filtered by
    derivative_filter_s), clipped to control_limits if given; the step shortened to divide the
    dead time."""
    if derivative_filter_s < 0:
        raise ValueError("derivative_filter_s must be >= 0")
    delay_steps = math.ceil(model.delay_s / step_s - 1e-9) if model.delay_s and step_s > 0 else 0
    h = model.delay_s / delay_steps if delay_steps else step_s
    return closed_loop(model, Pid(gains, h, derivative_filter_s, control_limits), setpoint, duration_s, h)
