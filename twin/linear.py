"""Linear thermal plants stepped exactly on the firmware's clock tick.

A plant is ``x' = A x + b u + E d`` with the heater input ``u`` (0..1 of full power, constant
over each 1.024 ms tick, since pins change only in the ISR) and slow disturbances ``d``
(ambient temperature). Outputs are ``y = C x + F d``: row 0 the sensor node, row 1 the heater
block. A and b may depend on the conditions (part fan, filament flow), which change only at
scenario events.

Zero-order hold on the tick is exact for such an input, so ``x[k+1] = Phi x[k] + g u[k] + H d``.
For a run of n ticks the engine needs the sensor at a few offsets and the state at the end:
those are fixed linear maps of (x0, u[0..n), d), cached per (n, offsets) once per condition, so a
160-tick control period costs two small matrix products however the PWM switches inside it.
Both caches are bounded (least recently used out): MAX_CACHED_MODELS conditions per plant, and
MAX_CACHED_RUNS run shapes per condition (a serial session's moves and host events cut runs at
ever new lengths), so a plant's cache stays under about MAX_CACHED_MODELS x MAX_CACHED_RUNS x 42 kB
(a 160-tick run sampled 16 times; tests/twin/test_model_cache.py).
A dead time shifts ``u`` by whole ticks (1.024 ms resolution).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

import numpy as np

from twin.clock import TICK_S

MAX_CACHED_MODELS = 64  # discretisations a LinearPlant keeps (LRU): fan x flow x radiation-bin states (a relay spans 20+ 0.5-C bins)
MAX_CACHED_RUNS = 48  # run shapes (n_ticks, offsets) a TickModel keeps (LRU): the control period's few, and some
SENSOR, BLOCK = 0, 1  # output rows


@dataclass(frozen=True)
class Lti:
    """Continuous-time model: states x, heater input u (0..1), disturbances d (degC)."""

    a: np.ndarray  # (n, n), 1/s
    b: np.ndarray  # (n,), state units per second at full power
    e: np.ndarray  # (n, m)
    c: np.ndarray  # (2, n): sensor and block temperatures
    f: np.ndarray  # (2, m): disturbance feed-through (e.g. ambient for rise-above-ambient models)


class TickModel:
    """One ``Lti`` discretised on the tick, with the multi-tick maps the engine asks for."""

    def __init__(self, lti: Lti, tick_s: float = TICK_S):
        n, m = lti.a.shape[0], lti.e.shape[1]
        # ZOH of [u, d] through the augmented exponential.
        aug = np.zeros((n + 1 + m, n + 1 + m))
        aug[:n, :n] = lti.a
        aug[:n, n] = lti.b
        aug[:n, n + 1 :] = lti.e
        import scipy.linalg  # here, not at start-up: a command's --help needs no scipy

        disc = scipy.linalg.expm(aug * tick_s)
        self.lti = lti
        self.phi = disc[:n, :n]
        self.g = disc[:n, n]
        self.h = disc[:n, n + 1 :]
        self._powers = [np.eye(n)]  # Phi^k
        self._u_resp = [np.zeros(n)]  # sum_{j<k} Phi^j g: response to u = 1 over k ticks
        self._d_resp = [np.zeros((n, m))]  # sum_{j<k} Phi^j H
        self._runs: OrderedDict[tuple, Any] = OrderedDict()  # (kind, n_ticks[, offsets]) -> cached maps, LRU

    def __repr__(self) -> str:
        return f"TickModel({self.phi.shape[0]} states, {self.h.shape[1]} disturbances, {len(self._runs)} runs cached)"

    def _extend(self, k: int) -> None:
        while len(self._powers) <= k:
            p = self._powers[-1]
            self._u_resp.append(self._u_resp[-1] + p @ self.g)
            self._d_resp.append(self._d_resp[-1] + p @ self.h)
            self._powers.append(self.phi @ p)

    def u_steps(self, n_ticks: int) -> np.ndarray:
        """S(k) for k = 0..n_ticks, (n_ticks + 1, n_x): the state k ticks into u = 1 from x = 0.

        A pulse u = 1 on ticks [a, b) adds ``S(s - a) - S(s - b)`` to the state at tick s >= b,
        which lets batch twins add up PWM pulses without a per-tick input array.
        """
        key = ("u_steps", n_ticks)
        table = self._cached(key)
        if table is None:
            self._extend(n_ticks)
            table = self._store(key, np.array(self._u_resp[: n_ticks + 1]))
        return table

    def run_maps(self, n_ticks: int, offsets: tuple[int, ...]) -> tuple:
        """Maps for a run of n ticks: outputs at ``offsets`` and the final state.

        Returns (Px (J, 2, n_x), Pu (J, 2, n_ticks), Pd (J, 2, m), Fx, Fu, Fd) with
        ``y[j] = Px[j] x0 + Pu[j] u + (Pd[j] + F) d`` and ``x_end = Fx x0 + Fu u + Fd d``.
        """
        key = (n_ticks, offsets)
        maps = self._cached(key)
        if maps is None:
            maps = self._store(key, self._build(n_ticks, offsets))
        return maps

    def _cached(self, key: tuple) -> Any:
        value = self._runs.get(key)
        if value is not None:
            self._runs.move_to_end(key)
        return value

    def _store(self, key: tuple, value: Any) -> Any:
        self._runs[key] = value
        if len(self._runs) > MAX_CACHED_RUNS:
            self._runs.popitem(last=False)
        return value

    def _build(self, n_ticks: int, offsets: tuple[int, ...]) -> tuple:
        self._extend(n_ticks)
        c = self.lti.c
        # impulse response of one tick of u at tick i, seen k ticks after its start: Phi^(k-1) g
        imp = np.array([self._powers[k] @ self.g for k in range(n_ticks)])  # (n_ticks, n_x)
        n_x, m = self.phi.shape[0], self.h.shape[1]
        px = np.array([c @ self._powers[s] for s in offsets]).reshape(len(offsets), 2, n_x)
        pu = np.zeros((len(offsets), 2, n_ticks))
        for j, s in enumerate(offsets):
            if s:
                pu[j, :, :s] = c @ imp[s - 1 :: -1][:s].T
        pd = np.array([c @ self._d_resp[s] + self.lti.f for s in offsets]).reshape(len(offsets), 2, m)
        fx = self._powers[n_ticks]
        fu = imp[::-1].T.copy() if n_ticks else np.zeros((n_x, 0))
        fd = self._d_resp[n_ticks]
        return px, pu, pd, fx, fu, fd


class LinearPlant:
    """A linear plant whose model depends on the conditions; stepped by runs of ticks.

    ``model_for(conditions)`` builds the continuous model for a hashable conditions key (fan,
    flow); discretisations are cached per key, the MAX_CACHED_MODELS most recently used ones
    (each holds up to MAX_CACHED_RUNS multi-tick maps: a host streaming moves at ever new feed
    rates must not grow the cache without end). An evicted key is rebuilt by the same
    deterministic computation, so the bound changes no result. ``d`` holds the disturbances.
    """

    def __init__(self, model_for: Callable[[Hashable], Lti], conditions: Hashable, x0, d, delay_ticks: int = 0):
        self._model_for = model_for
        self._models: OrderedDict[Hashable, TickModel] = OrderedDict()
        self.set_conditions(conditions)
        self.x = np.array(x0, dtype=float)
        self.d = np.array(d, dtype=float)
        self.delay_ticks = int(delay_ticks)
        self._u_history = np.zeros(self.delay_ticks)  # the last delay_ticks inputs, oldest first

    def __repr__(self) -> str:
        temps = self.temps_c()
        return f"{type(self).__name__}(sensor {temps[SENSOR]:.2f} C, block {temps[BLOCK]:.2f} C, " \
               f"conditions {self.conditions}, delay {self.delay_ticks} ticks)"

    def set_conditions(self, conditions: Hashable) -> None:
        """New fan/flow conditions (a scenario event): pick or build their discretisation."""
        model = self._models.get(conditions)
        if model is None:
            model = self._models[conditions] = TickModel(self._model_for(conditions))
            if len(self._models) > MAX_CACHED_MODELS:
                self._models.popitem(last=False)
        else:
            self._models.move_to_end(conditions)
        self.conditions = conditions
        self.model = model

    def _delayed(self, u: np.ndarray) -> np.ndarray:
        if not self.delay_ticks:
            return u
        return np.concatenate((self._u_history, u))[: len(u)]

    def outputs(self, u: np.ndarray, offsets: tuple[int, ...]) -> np.ndarray:
        """Sensor and block temperatures (J, 2) at tick offsets into a run with inputs u; no state change.

        An offset k sees the inputs of ticks 0..k-1 only.
        """
        px, pu, pd, *_ = self.model.run_maps(len(u), offsets)
        return px @ self.x + pu @ self._delayed(u) + pd @ self.d

    def advance(self, u: np.ndarray) -> None:
        """Run len(u) ticks with heater inputs u."""
        n = len(u)
        *_, fx, fu, fd = self.model.run_maps(n, ())
        self.x = fx @ self.x + fu @ self._delayed(u) + fd @ self.d
        if self.delay_ticks:
            self._u_history = np.concatenate((self._u_history, u))[-self.delay_ticks :]

    def temps_c(self) -> np.ndarray:
        """Sensor and block temperatures now."""
        return self.model.lti.c @ self.x + self.model.lti.f @ self.d
