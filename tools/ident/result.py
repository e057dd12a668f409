"""FitResult: a model fitted to a log, with what the data could and could not tell.

    result = fit_model("three_node", t_s, temp_c, duty, ambient_c=22.0)
    result.spec()                      # the fitted plant (twin/plants.py Lumped or TransferFunction)
    result.ambient_c                   # the ambient it was fitted at (the spec carries none)
    for name, low, high, source in result.spread():
        ...                            # each parameter the data leave open, its plausible range
    result.spec_with(sensor_responsiveness_per_s=0.3)   # the plant at any point of those ranges

``spread()`` is what a robust tuner's ensemble covers: every parameter the data do not identify
(tools/ident/plausible.py: standard error beyond the value, at a bound, or held by assumption)
with a physically plausible range and its source, and every poorly identified one (a relative
standard error above POORLY_IDENTIFIED_REL) within two standard errors, clipped to that range.
``spec_with(**values)`` builds the plant for any values inside those ranges (ValueError outside).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from tools.ident.lsq import information_criterion
from tools.ident.response import model_response, model_spec
from twin.plants import Lumped, Spec

@dataclass(frozen=True)
class FitResult:
    """A model fitted to a segment: parameters (units in their names) with standard errors, the
    values held fixed, and the residuals (model - log) at the segment's samples. initial_c is the
    temperature every node starts at (for the transfer functions: the equilibrium that holds it)."""

    model: str
    params: dict[str, float]  # fitted
    std_errors: dict[str, float]  # NaN: stopped at a bound; inf: the segment does not determine it
    fixed: dict[str, float]  # held: power_w, ambient_c when given, ...
    residuals_c: np.ndarray
    loss: str = "linear"  # the lumped models' heat loss: "linear" or "radiating" (LOSSES)

    @property
    def values(self) -> dict[str, float]:
        return {**self.fixed, **self.params}

    @property
    def rmse_c(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals_c))))

    @property
    def max_abs_residual_c(self) -> float:
        return float(np.max(np.abs(self.residuals_c)))

    @property
    def n_samples(self) -> int:
        return len(self.residuals_c)

    def spec(self) -> Spec:
        """The fitted plant as a twin/plants.py spec (for twin.plants.Plant)."""
        return model_spec(self.model, self.values)

    def simulate(self, t_s: np.ndarray, duty: np.ndarray, initial_c: float | None = None) -> np.ndarray:
        """The fitted model's reading at t_s for a zero-order-hold duty, from initial_c (default: the fit's)."""
        values = self.values if initial_c is None else {**self.values, "initial_c": initial_c}
        return model_response(self.model, values, np.asarray(t_s, float), np.asarray(duty, float))

    def derived(self) -> dict[str, float]:
        """Numbers that do not depend on the assumed power: for the lumped models the heating rate
        at full power (C/s), the rise at full power (C), the loss time constant and the sensor lag.
        With the radiating loss the rise solves P = (A + h(T)) (T - Ta), h the radiation's secant
        conductance (twin/plants.py ``Lumped.radiation_w_k``), and the time constant is the one near
        ambient, where h is 4 sigma eps area Ta^3: both scale with P like C, A and the area."""
        v = self.values
        spec = self.spec()
        if not isinstance(spec, Lumped):
            return {}
        capacity_j_k = v["block_heat_capacity_j_k"] + v.get("cartridge_heat_capacity_j_k", 0.0)
        ambient_c, power_w, linear_w_k = v["ambient_c"], v["power_w"], v["ambient_xfer_w_k"]
        near_ambient_w_k = linear_w_k + spec.radiation_w_k(ambient_c, ambient_c)
        rise_c = power_w / near_ambient_w_k  # the secant conductance only grows with temperature: an upper bound
        if not spec.linear:
            rise_c = scipy.optimize.brentq(
                lambda r: (linear_w_k + spec.radiation_w_k(ambient_c + r, ambient_c)) * r - power_w, 0.0, rise_c)
        return {"heating_rate_c_s": power_w / capacity_j_k,
                "rise_at_full_power_c": float(rise_c),
                "loss_time_constant_s": capacity_j_k / near_ambient_w_k,
                "sensor_lag_s": 1.0 / v["sensor_responsiveness_per_s"]}


def aic(result: FitResult) -> float:
    """``information_criterion`` of a fitted model: its residuals and its fitted parameters."""
    return information_criterion(result.residuals_c, len(result.params))

