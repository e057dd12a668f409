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

import math
from dataclasses import dataclass

import numpy as np

from tools.ident.lsq import information_criterion
from tools.ident.plausible import Range, identification, plausible
from tools.ident.response import model_response, model_spec
from twin.plants import Lumped, Spec

NOT_PLANT = ("initial_c",)  # a fitted value that belongs to the segment, not to the plant
# The parameters that set each model's lags (the rest set its static gain): data that identify none
# of them say nothing about the dynamics a tuning rule needs.
LAGS = {"fopdt": ("time_constant_s", "delay_s"), "sopdt": ("lag1_s", "lag2_s", "delay_s"),
        "two_node": ("block_heat_capacity_j_k", "sensor_responsiveness_per_s"),
        "three_node": ("block_heat_capacity_j_k", "cartridge_xfer_w_k", "sensor_responsiveness_per_s")}

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
    evidence: str = "trace"  # what was fitted: a logged "trace", "relay results" or both
    heater: str = "extruder"  # whose plausible ranges apply: a hotend's or a bed's
    assumed: tuple[str, ...] = ("cartridge_heat_capacity_j_k",)  # held values nobody measured
    anchor_c: float | None = None  # relay data: the temperature at which the static loss was measured

    @property
    def ambient_c(self) -> float:
        """The ambient the plant was fitted at (a spec carries none: run it at this one)."""
        return self.values["ambient_c"]

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
        import scipy.optimize  # here: a command's start-up needs no scipy
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


    def identification(self) -> dict[str, str]:
        """Each fitted parameter's standing: "identified", "poorly identified" or "not identified"
        (tools/ident/plausible.py); held ones by assumption are "assumed"."""
        out = {name: identification(value, self.std_errors[name])
               for name, value in self.params.items() if name not in NOT_PLANT}
        out.update({name: "assumed" for name in self.assumed if name in self.fixed})
        return out

    def degenerate(self) -> str | None:
        """Why the fit cannot serve a tuner (none of the model's lags identified), or None."""
        standing = self.identification()
        lags = [name for name in LAGS[self.model] if name in standing]
        if lags and all(standing[name] == "not identified" for name in lags):
            return (f"the data identify none of {self.model}'s lags ({', '.join(lags)}: standard errors beyond "
                    "their values or on a bound)")
        return None

    def parameter_lines(self) -> list[str]:
        """Each parameter as twin-fit prints it: value, standard error (or why none), how well identified."""
        standing = self.identification()
        lines = []
        for name, value in self.params.items():
            error = self.std_errors[name]
            spread = "at its bound" if np.isnan(error) else "not determined" if np.isinf(error) else f"+- {error:.2g}"
            lines.append(f"  {name:30} {value:12.5g}  {spread:14} {standing.get(name, '')}".rstrip())
        lines += [f"  {name:30} {value:12.5g}  {'held':14} {standing.get(name, '')}".rstrip()
                  for name, value in self.fixed.items() if name != "initial_c" or "initial_c" not in self.params]
        return lines

    def spread(self) -> list[Range]:
        """(name, low, high, source) of every parameter the data leave open: not identified or assumed,
        its plausible range (widened to take in the fitted value); poorly identified, two standard
        errors either way (a positive parameter stays positive)."""
        out = []
        for name, standing in self.identification().items():
            value = self.values[name]
            if standing == "poorly identified":  # two standard errors, within what is plausible at all
                error = 2.0 * abs(self.std_errors[name])
                low = value - error if name in ("ambient_c", "delay_s") else max(value - error, value / 10.0)
                r = plausible(name, self.heater, value)
                out.append(Range(name, max(low, 0.0 if name == "delay_s" else -math.inf, min(r.low, value)),
                                 min(value + error, max(r.high, value)),
                                 f"the fit: two standard errors either way, within {r.low:.4g}..{r.high:.4g} "
                                 f"({r.source})"))
            elif standing != "identified":
                r = plausible(name, self.heater, value)
                out.append(r._replace(low=min(r.low, value), high=max(r.high, value)))
        return out

    def spec_with(self, **values: float) -> Spec:
        """The fitted plant with some parameters set to other values (for a parameter in ``spread()``
        within its range; ValueError names an unknown parameter or a value outside). ambient_c is
        not in a spec: for relay data, whose static loss was measured at ``anchor_c``, another
        ambient rescales the loss so that the measured hold stays (the gain or the losses scale by
        (anchor - ambient) / (anchor - new ambient)); run the plant at that ambient."""
        ranges = {r.name: r for r in self.spread()}
        known = (set(self.params) | set(self.fixed)) - set(NOT_PLANT)
        for name, value in values.items():
            if name not in known:
                raise ValueError(f"{self.model} has no parameter {name!r}; valid: {', '.join(sorted(known))}")
            r = ranges.get(name)
            if not math.isfinite(value) or (r is not None and not r.low <= value <= r.high):
                raise ValueError(f"{name}={value!r} is outside its range {r.low:.4g}..{r.high:.4g}" if r
                                 else f"{name}={value!r}: must be a finite number")
        new = {**self.values, **values}
        if "ambient_c" in values and self.anchor_c is not None:
            scale = (self.anchor_c - self.ambient_c) / (self.anchor_c - values["ambient_c"])
            for name in ("gain_c",) if self.model in ("fopdt", "sopdt") else ("ambient_xfer_w_k",
                                                                               "fan_ambient_xfer_w_k"):
                if name in new and name not in values:
                    new[name] = new[name] / scale if name == "gain_c" else new[name] * scale
        return model_spec(self.model, new)


def aic(result: FitResult) -> float:
    """``information_criterion`` of a fitted model: its residuals and its fitted parameters."""
    return information_criterion(result.residuals_c, len(result.params))

