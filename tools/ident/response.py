"""A model's reading for a logged duty: the twin's own plants stepped on the firmware tick.

The logged duty is held from each sample to the next (zero-order hold) and run through the twin's
plants (twin/linear.py ``LinearPlant``, exact for these linear models; no second integrator). Dead
time is whole ticks (1.024 ms); a delay_s between two whole ticks interpolates the two responses
linearly, so the residuals are a smooth function of delay_s for an optimiser. A radiating plant is
stepped by ``radiating_response``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg

from twin.linear import SENSOR, TICK_S, Lti
from twin.plants import Lumped, Plant, Spec, TransferFunction

def zoh_response(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The plant's sensor at the instants t_s (from t_s[0]), its heater at duty[i] from t_s[i] to
    t_s[i + 1]; instants on the tick grid (1.024 ms). A radiating plant: ``radiating_response``."""
    if not plant.linear:
        return radiating_response(plant, t_s, duty)
    ticks = np.rint((t_s - t_s[0]) / TICK_S).astype(int)
    out = np.empty(len(t_s))
    out[0] = plant.temps_c()[SENSOR]
    for i, n in enumerate(np.diff(ticks)):
        plant.advance(np.full(n, duty[i]))
        plant.relinearise()
        out[i + 1] = plant.temps_c()[SENSOR]
    return out


def radiating_response(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """A radiating lumped plant's sensor at the instants t_s, from its state now: over each sample
    interval the plant's own model (``Lumped.lti``) linearised at the block's temperature at the
    interval's start (the secant radiation conductance, docs/plants.md "Radiation"), stepped exactly
    for that interval's duty by one matrix exponential of the model augmented with its constant input.

    The engine relinearises the same model between its runs (at most 160 ticks) in 0.5 C bins, each
    bin a discretisation of its own; per sample, unbinned, the residuals are smooth in the radiation
    parameter and a fit does not rebuild a tick model for every bin (about 5 s against 0.05 s per
    evaluation on the onionheater pulse)."""
    spec = plant.spec
    assert isinstance(spec, Lumped)  # the radiating term is a lumped model's
    x = plant.x.copy()
    n = len(x)
    out = np.empty(len(t_s))
    out[0] = plant.temps_c()[SENSOR]
    augmented = np.zeros((n + 1, n + 1))
    for i, step_s in enumerate(np.diff(t_s)):
        lti = spec.lti(spec.conditions(plant.fan, plant.flow_mm_s, plant.ambient_c, float(x[0]))._replace(
            block_bin_c=float(x[0])))
        augmented[:n, :n] = lti.a
        augmented[:n, n] = lti.b * duty[i] + lti.e @ plant.d
        x = (scipy.linalg.expm(augmented * step_s) @ np.r_[x, 1.0])[:n]
        out[i + 1] = lti.c[SENSOR] @ x
    plant.x = x
    return out


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


