"""A model's reading for a logged duty: the twin's own plants, their exact zero-order hold on the tick.

The logged duty is held from each sample to the next (zero-order hold) and run through the twin's
plants (twin/linear.py ``LinearPlant``'s model and state, stepped exactly from one breakpoint to the
next as its tick maps would step them tick by tick; no second integrator). Dead time is whole ticks
(1.024 ms); a delay_s between two whole ticks interpolates the two responses
linearly, so the residuals are a smooth function of delay_s for an optimiser. A radiating plant is
stepped by ``radiating_response``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.linear import SENSOR, TICK_S, Lti
from twin.plants import Lumped, Plant, Spec, TransferFunction

def zoh_response(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The plant's sensor at the instants t_s (from t_s[0]), its heater at duty[i] from t_s[i] to
    t_s[i + 1]; instants on the tick grid (1.024 ms), the dead time in whole ticks after the plant's own
    history of inputs; the plant is left at t_s[-1]. A radiating plant: ``radiating_response``.

    Exact for a linear plant as the engine's tick maps are (the same zero-order hold), but stepped from
    breakpoint to breakpoint (a reading, or a change of the delayed input) with one map per distinct
    interval length, not tick by tick: a fit evaluates it hundreds of times."""
    if not plant.linear:
        return radiating_response(plant, t_s, duty)
    ticks = np.rint((np.asarray(t_s, float) - t_s[0]) / TICK_S).astype(np.int64)
    duty = np.asarray(duty, float)
    delay = plant.delay_ticks
    history = plant._u_history  # the inputs of the delay_ticks ticks before t_s[0], oldest first
    runs = np.flatnonzero(np.r_[True, np.diff(history) != 0]) if delay else np.zeros(0, np.int64)
    change_at = np.r_[runs, ticks[:-1] + delay]  # where the delayed input takes each new value
    change_to = np.r_[history[runs], duty[:-1]]
    points = np.union1d(ticks, change_at[change_at <= ticks[-1]])
    source = np.searchsorted(change_at, points[:-1], side="right") - 1
    u = change_to[source]
    lengths, which = np.unique(np.diff(points), return_inverse=True)
    lti = plant.model.lti
    phi, g, h = _interval_maps(lti, lengths * TICK_S)
    hd = h @ plant.d
    x = plant.x.copy()
    states = np.empty((len(points), len(x)))
    states[0] = x
    for k, (j, u_k) in enumerate(zip(which, u)):
        x = phi[j] @ x + g[j] * u_k + hd[j]
        states[k + 1] = x
    plant.x = x
    if delay:  # the raw inputs of the last delay ticks: the history of what follows
        tail = np.arange(ticks[-1] - delay, ticks[-1])
        sample = np.searchsorted(ticks, tail, side="right") - 1
        plant._u_history = np.where(tail >= 0, duty[np.maximum(sample, 0)], history[np.clip(tail + delay, 0, delay - 1)])
    return states[np.searchsorted(points, ticks)] @ lti.c[SENSOR] + lti.f[SENSOR] @ plant.d


def _interval_maps(models: Lti | list[Lti], lengths_s: np.ndarray, repeat: int = 1
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-order hold of x' = A x + b u + E d over each interval length: (Phi, g, H) stacked per length;
    with a list of models, each taken for ``repeat`` consecutive lengths."""
    import scipy.linalg  # here: a command's start-up needs no scipy
    models = [models] if isinstance(models, Lti) else models
    n, m = models[0].a.shape[0], models[0].e.shape[1]
    aug = np.zeros((len(lengths_s), n + 1 + m, n + 1 + m))
    for i, lti in enumerate(models):
        rows = slice(i * repeat, (i + 1) * repeat) if len(models) > 1 else slice(None)
        aug[rows, :n, :n], aug[rows, :n, n], aug[rows, :n, n + 1:] = lti.a, lti.b, lti.e
    disc = scipy.linalg.expm(aug * np.asarray(lengths_s, float)[:, None, None])
    return disc[:, :n, :n], disc[:, :n, n], disc[:, :n, n + 1:]


def radiating_response(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """A radiating lumped plant's sensor at the instants t_s (on the tick grid), from its state now: over
    each sample interval the plant's own model (``Lumped.lti``) linearised at the block's temperature at
    the interval's start (the secant radiation conductance, docs/plants.md "Radiation") and stepped
    exactly for that interval's duty.

    The interval's map (zero-order hold of the linearised model) is interpolated linearly between the
    maps at the two nearest points of a RADIATING_MAP_STEP_C grid of block temperatures, built as the
    run reaches them (one batched matrix exponential per GRID_CHUNK points and interval length): the
    residuals stay continuous in the block temperature and smooth in the parameters, as a fit needs,
    and a run costs a few hundred exponentials, not one per sample. The interpolation's error is
    second order in the grid step (tests/tools/ident/test_response.py bounds it against exponentials
    taken at every sample)."""
    spec = plant.spec
    assert isinstance(spec, Lumped)  # the radiating term is a lumped model's
    ticks = np.rint((np.asarray(t_s, float) - t_s[0]) / TICK_S).astype(np.int64)
    lengths, which = np.unique(np.diff(ticks), return_inverse=True)
    grid = _RadiatingMaps(plant, lengths * TICK_S)
    x = plant.x.copy()
    c = plant.model.lti.c[SENSOR]
    out = np.empty(len(ticks))
    out[0] = c @ x
    xa = np.ones(len(x) + 2)  # [x, u, 1]: one matrix [Phi | g | H d] steps it
    for i, (j, u) in enumerate(zip(which, np.asarray(duty, float))):
        xa[:-2], xa[-2] = x, u
        where = x[0] / RADIATING_MAP_STEP_C
        k = math.floor(where)
        low = grid.point(k)[j] @ xa
        x = low + (where - k) * (grid.point(k + 1)[j] @ xa - low)
        out[i + 1] = c @ x
    plant.x = x
    return out


RADIATING_MAP_STEP_C = 5.0  # radiating_response's grid of linearisation temperatures
GRID_CHUNK = 16  # grid points built at once


class _RadiatingMaps:
    """The interval maps [Phi | g | H d] of a radiating plant at grid points of block temperature, built on
    demand, one per interval length."""

    def __init__(self, plant: Plant, lengths_s: np.ndarray):
        self.plant, self.lengths_s = plant, lengths_s
        self.maps: dict[int, np.ndarray] = {}  # grid point -> (lengths, n, n + 2)

    def point(self, k: int) -> np.ndarray:
        if k not in self.maps:
            first = k - GRID_CHUNK // 2
            self._build([p for p in range(first, first + GRID_CHUNK) if p not in self.maps])
        return self.maps[k]

    def _build(self, points: list[int]) -> None:
        plant, spec = self.plant, self.plant.spec
        assert isinstance(spec, Lumped)
        models = [spec.lti(spec.conditions(plant.fan, plant.flow_mm_s, plant.ambient_c, p * RADIATING_MAP_STEP_C)
                           ._replace(block_bin_c=p * RADIATING_MAP_STEP_C)) for p in points]
        n_len = len(self.lengths_s)
        phi, g, h = _interval_maps(models, np.tile(self.lengths_s, len(points)), repeat=n_len)
        affine = np.concatenate([phi, g[:, :, None], (h @ plant.d)[:, :, None]], axis=2)
        for i, p in enumerate(points):
            self.maps[p] = affine[i * n_len:(i + 1) * n_len]


# --- the models ----------------------------------------------------------------------------------


def spec_lti(spec: Spec, ambient_c: float) -> Lti:
    """A spec's continuous model at ambient_c with the part fan off and no flow (a radiating one
    linearised with the block at ambient)."""
    if isinstance(spec, TransferFunction):
        return spec.lti()
    return spec.lti(spec.conditions(0.0, 0.0, ambient_c, ambient_c))


def model_spec(model: str, params: dict[str, float]) -> Spec:
    """The twin's plant for a model's parameters (ambient_c aside): TransferFunction or Lumped."""
    p = params
    if model == "fopdt":
        return TransferFunction(p["gain_c"], 1.0, lag1_s=p["time_constant_s"], delay_s=p["delay_s"])
    if model == "sopdt":
        return TransferFunction(p["gain_c"], 1.0, lag1_s=p["lag1_s"], lag2_s=p["lag2_s"], delay_s=p["delay_s"])
    names = {f.name for f in dataclasses.fields(Lumped)}
    lumped = {k: v for k, v in p.items() if k in names}
    lumped.setdefault("fan_ambient_xfer_w_k", p["ambient_xfer_w_k"])  # logs carry no part-fan speed
    return Lumped(**lumped)


def model_response(model: str, values: dict[str, float], t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The model's sensor at t_s for the zero-order-hold duty, from initial_c (every node, or the
    equilibrium holding it), the delay interpolated between whole ticks."""
    spec = model_spec(model, values)

    def run(s: Spec) -> np.ndarray:
        return zoh_response(Plant(model, s, values["ambient_c"], values["initial_c"]), t_s, duty)

    if not isinstance(spec, TransferFunction):
        return run(spec)
    whole, frac = divmod(spec.delay_s / TICK_S, 1.0)
    early = run(dataclasses.replace(spec, delay_s=whole * TICK_S))
    if not frac:
        return early
    return (1.0 - frac) * early + frac * run(dataclasses.replace(spec, delay_s=(whole + 1.0) * TICK_S))


