"""One protocol for the four engines: ``Twin``, ``BatchTwin``, ``KlipperTwin`` and ``KlipperBatch``.

An engine is one or more lanes (a single twin is one lane, a batch one per candidate) on one clock.
Whatever runs in it, a caller drives it the same way::

    engine.hotend.target_c = 210                        # a per-heater handle: every lane's target
    engine.schedule_plants(300.0, lambda plant: plant.set_inputs(1.0, 0.0, 25.0))   # part fan on
    result = engine.run(900)                            # RunResult: (rows,) or, with lanes, (rows, lanes)
    engine.halted                                       # bool, or (lanes,) bool for a batch
    engine.trips()                                      # [Trip(lane, heater, reason), ...]

Lane-shaped values follow ``RunResult``'s rule: a batch's carry a lane axis, a single twin's do not.
``Stack`` puts single twins side by side as the lanes of one engine (a candidate the batches cannot
run), so a tuner writes one runner: a batch, or a ``Stack`` of twins, behind the same protocol.

(``twin.engine.ENGINES`` names something else: how a ``Twin`` steps its clock, fast or tick by tick.)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

from twin.limits import DURATION_MAX_S, checked
from twin.result import FIELDS, RunResult


@dataclass(frozen=True)
class Trip:
    """A lane's board halted by its protection: the heater (the result's name) and the firmware's words."""

    lane: int  # 0 on a single twin
    heater: str  # "hotend", "bed", or a Klipper heater's own name
    reason: str  # "Thermal Runaway", "MAXTEMP triggered", "ADC out of range", ...


@runtime_checkable
class Heater(Protocol):
    """One heater of an engine: its name in the result, its target (on every lane) and its lanes' controllers."""

    name: str

    @property
    def target_c(self) -> float: ...

    @target_c.setter
    def target_c(self, value: float) -> None: ...

    @property
    def controllers(self) -> tuple[Any, ...]: ...


@runtime_checkable
class Engine(Protocol):
    """What every engine does: handles, events, ``run(seconds) -> RunResult``, ``halted`` and the trips."""

    @property
    def n_lanes(self) -> int: ...

    @property
    def time_s(self) -> float: ...

    @property
    def handles(self) -> Mapping[str, Heater]: ...

    @property
    def hotend(self) -> Heater: ...

    @property
    def halted(self) -> bool | np.ndarray: ...

    def schedule(self, at_s: float, action: Callable[[Any], None]) -> None:
        """``action(engine)`` at ``at_s``."""

    def schedule_plants(self, at_s: float, action: Callable[[Any], None]) -> None:
        """``action(plant)`` on every distinct plant at ``at_s``: a change of its inputs (fan, flow, ambient, a
        load), never of its state."""

    def run(self, seconds: float) -> RunResult: ...

    def run_until(self, t_s: float) -> None: ...

    def result(self) -> RunResult: ...

    def trips(self) -> list[Trip]: ...


class _Runnable(Protocol):
    @property
    def time_s(self) -> float: ...

    @property
    def handles(self) -> Mapping[str, Heater]: ...

    def run_until(self, t_s: float) -> None: ...

    def result(self) -> RunResult: ...


class Runs:
    """``run`` and ``hotend`` for an engine that has ``time_s``, ``run_until``, ``result`` and ``handles``."""

    def run(self: _Runnable, seconds: float) -> RunResult:
        """Run ``seconds`` more of virtual time; the result of everything recorded since time 0."""
        checked("seconds", seconds, 0.0, DURATION_MAX_S - self.time_s, "s", above=True)
        self.run_until(self.time_s + seconds)
        return self.result()

    @property
    def hotend(self: _Runnable) -> Heater:
        """The hotend's handle (AttributeError on an engine without one)."""
        if "hotend" not in self.handles:
            raise AttributeError(f"this engine has no hotend (heaters: {', '.join(self.handles)})")
        return self.handles["hotend"]


class LaneHeater:
    """A heater handle from the engine's own accessors: the target's getter and setter, the controllers."""

    def __init__(self, name: str, get_target: Callable[[], float], set_target: Callable[[float], None],
                 controllers: Callable[[], Sequence[Any]]):
        self.name = name
        self._get, self._set, self._controllers = get_target, set_target, controllers

    @property
    def target_c(self) -> float:
        return self._get()

    @target_c.setter
    def target_c(self, value: float) -> None:
        self._set(value)

    @property
    def controllers(self) -> tuple[Any, ...]:
        return tuple(self._controllers())

    def __repr__(self) -> str:
        return f"LaneHeater({self.name!r}, target_c={self.target_c:g}, lanes={len(self.controllers)})"


class Stack(Runs):
    """Single twins (``Twin`` or ``KlipperTwin``) side by side as the lanes of one engine.

    Each runs on its own, the same events scheduled on each; the result puts their heaters' arrays side by
    side, (rows, lanes), on the clock of the running lane with the most rows: their readings share it, and a
    halted lane's columns are interpolated onto it (a Klipper lane that shut down holds its last report, as
    ``KlipperBatch``'s lanes do; a Marlin board records on its own cadence once halted).
    ``schedule`` runs its action on each twin."""

    def __init__(self, engines: Sequence[Engine]):
        if not engines:
            raise ValueError("a stack needs at least one engine")
        for lane, engine in enumerate(engines):
            if engine.n_lanes != 1:
                raise ValueError(f"lane {lane}: a stack holds single twins, not an engine of {engine.n_lanes} lanes")
        self.engines = list(engines)
        self.handles = {name: self._handle(name) for name in self.engines[0].handles}

    def _handle(self, name: str) -> LaneHeater:
        def set_target(value: float) -> None:
            for engine in self.engines:
                engine.handles[name].target_c = value

        return LaneHeater(name, lambda: self.engines[0].handles[name].target_c, set_target,
                          lambda: [c for engine in self.engines for c in engine.handles[name].controllers])

    @property
    def n_lanes(self) -> int:
        return len(self.engines)

    @property
    def time_s(self) -> float:
        return self.engines[0].time_s

    @property
    def halted(self) -> np.ndarray:
        return np.array([bool(engine.halted) for engine in self.engines])

    def schedule(self, at_s: float, action: Callable[[Any], None]) -> None:
        for engine in self.engines:
            engine.schedule(at_s, action)

    def schedule_plants(self, at_s: float, action: Callable[[Any], None]) -> None:
        for engine in self.engines:
            engine.schedule_plants(at_s, action)

    def run_until(self, t_s: float) -> None:
        for engine in self.engines:
            engine.run_until(t_s)

    def result(self) -> RunResult:
        runs = [engine.result() for engine in self.engines]
        running = [run for run, engine in zip(runs, self.engines) if not engine.halted] or runs
        clock = max(running, key=lambda r: len(r.t_s))
        columns = {name: {f: np.column_stack([_on_clock(clock.t_s, r.heaters[name].t_s, getattr(r.heaters[name], f))
                                              for r in runs]) for f in FIELDS}
                   for name in clock.heaters}
        events = sorted((t_s, f"lane {lane}: {text}") for lane, r in enumerate(runs) for t_s, text in r.events)
        return RunResult.from_columns(clock.t_s, columns, clock.fan, events, f"{runs[0].label}, {self.n_lanes} lanes")

    def trips(self) -> list[Trip]:
        return [replace(trip, lane=lane) for lane, engine in enumerate(self.engines) for trip in engine.trips()]

    def __repr__(self) -> str:
        return f"Stack({self.n_lanes} lanes: {self.engines[0]!r}, ...)"


def each_plant(action: Callable[[Any], None]) -> Callable[[Any], None]:
    """An engine's event that runs ``action(plant)`` on each of the engine's ``plants``."""
    def apply(engine: Any) -> None:
        for plant in engine.plants:
            action(plant)

    return apply


def _on_clock(t_s: np.ndarray, own_t_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A lane's column on the stack's clock (its own when they are the same)."""
    if np.array_equal(t_s, own_t_s):
        return values
    if not len(own_t_s):
        return np.full(len(t_s), np.nan)
    return np.interp(t_s, own_t_s, values)
