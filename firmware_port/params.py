"""A controller's tunable parameters, declared beside it: names, units, bounds, scale, defaults.

A ``ParamSpace`` is what a tuner needs to know about a controller and nothing more: the
parameters (a vector x, in the firmware's own units), where a search may go, and a factory that
builds a fresh controller from x. The firmware builds declare theirs (firmware_port/firmwares.py
``param_space``); a user's controller declares its own::

    SPACE = ParamSpace("smith_pid", (Param("kp", "counts/C", 0.0, 100.0, 20.0),
                                     Param("ti_s", "s", 1.0, 1000.0, 60.0, log=True)),
                       factory=lambda kp, ti_s: SmithPid(kp, ti_s))

``held`` maps x to the nearest values the firmware can hold (its fixed-point quanta): the
parameters a tuner prints are those. ``pid=True`` says the parameters are (Kp, Ki, Kd) in Marlin's M301 units and the factory's
controller is a ``Tunable`` PID: tuning rules, the idealised and Klipper loops apply to it.
``autotune`` names the firmware's own autotune of the family (M303 for a PID, M306 T for MPC): a
tuner runs it on the same twin as the reference to beat. ``log=True`` asks optimisers to search that parameter on a log scale (ranges
that span decades); its bounds must then be positive.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX, Controller, PidGains


@dataclass(frozen=True)
class Param:
    """One parameter: name, unit, bounds [low, high], the firmware's default value, log-scale search."""

    name: str
    unit: str
    low: float
    high: float
    default: float
    log: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ValueError(f"parameter {self.name}: bounds must be finite with low < high, got "
                             f"{self.low!r}..{self.high!r}")
        if not self.low <= self.default <= self.high:
            raise ValueError(f"parameter {self.name}: default {self.default!r} outside {self.low:g}..{self.high:g}")
        if self.log and self.low <= 0:
            raise ValueError(f"parameter {self.name}: a log-scale parameter needs low > 0, got {self.low!r}")


@dataclass(frozen=True)
class ParamSpace:
    """A controller family: its parameters and ``factory(*x) -> Controller``."""

    name: str
    params: tuple[Param, ...]
    factory: Callable[..., Controller]
    pid: bool = False
    held: Callable[..., tuple[float, ...]] | None = None  # x -> the nearest values the firmware can hold
    autotune: str | None = None  # the firmware's own autotune of this family ("M303", "M306 T"), if any

    def __post_init__(self) -> None:
        names = [p.name for p in self.params]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"controller {self.name}: parameter names must be unique and non-empty, got {names}")
        if self.pid and names != ["kp", "ki", "kd"]:
            raise ValueError(f"controller {self.name}: a PID space has parameters kp, ki, kd, got {names}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    @property
    def dims(self) -> int:
        return len(self.params)

    @property
    def defaults(self) -> np.ndarray:
        return np.array([p.default for p in self.params])

    @property
    def bounds(self) -> np.ndarray:
        """(d, 2): each parameter's [low, high]."""
        return np.array([(p.low, p.high) for p in self.params])

    def inside(self, x: np.ndarray) -> np.ndarray:
        """Rows of x (N, d) that are finite and within the bounds: (N,) bool."""
        x = np.atleast_2d(np.asarray(x, float))
        b = self.bounds
        return np.all(np.isfinite(x) & (x >= b[:, 0]) & (x <= b[:, 1]), axis=1)

    def check(self, x: Sequence[float] | np.ndarray) -> np.ndarray:
        """x as a float vector; ValueError naming the first parameter that is missing or out of bounds."""
        vector = np.asarray(x, float).ravel()
        if vector.size != self.dims:
            raise ValueError(f"controller {self.name} takes {self.dims} parameters ({', '.join(self.names)}), "
                             f"got {vector.size}")
        for p, value in zip(self.params, vector):
            if not (math.isfinite(value) and p.low <= value <= p.high):
                raise ValueError(f"{self.name} parameter {p.name}={float(value)!r} outside {p.low:g}..{p.high:g} {p.unit}")
        return vector

    def make(self, x: Sequence[float] | np.ndarray) -> Controller:
        """A fresh controller from x (checked against the bounds, then held as the firmware holds it)."""
        return self.factory(*self.hold(self.check(x)))

    def hold(self, x: Sequence[float] | np.ndarray) -> np.ndarray:
        """x as the firmware holds it (its fixed-point quanta); unchanged where the space declares none."""
        vector = np.asarray(x, float).ravel()
        return vector if self.held is None else np.array(self.held(*(float(v) for v in vector)), float)

    def describe(self, x: Sequence[float] | np.ndarray) -> str:
        """``name value unit`` for each parameter, 4 significant digits."""
        return ", ".join(f"{p.name} {v:.4g} {p.unit}".rstrip() for p, v in zip(self.params, np.ravel(x)))

    # -- search coordinates: log-scale parameters as their logarithm --------------------------------
    @property
    def _log_mask(self) -> np.ndarray:
        return np.array([p.log for p in self.params])

    def to_search(self, x: np.ndarray) -> np.ndarray:
        """Parameters (N, d) or (d,) -> search coordinates (log10 where ``log``)."""
        x = np.asarray(x, float)
        return np.where(self._log_mask, np.log10(np.where(self._log_mask, x, 1.0)), x)

    def from_search(self, z: np.ndarray) -> np.ndarray:
        """Search coordinates -> parameters (inverse of ``to_search``)."""
        z = np.asarray(z, float)
        return np.where(self._log_mask, 10.0 ** np.where(self._log_mask, z, 0.0), z)


def pid_params(default: PidGains) -> tuple[Param, Param, Param]:
    """Kp, Ki, Kd in M301 units over the domain the firmware's PID accepts, defaults from ``default``."""
    return (Param("kp", "counts/C", 0.0, KP_MAX, default.kp), Param("ki", "counts/(C s)", 0.0, KI_MAX, default.ki),
            Param("kd", "counts s/C", 0.0, KD_MAX, default.kd))
