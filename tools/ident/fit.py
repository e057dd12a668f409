"""Plant identification from logged series: FOPDT, SOPDT and the twin's lumped hotend/bed models
fitted to segments by least squares (tools/ident/lsq.py), with standard errors and residuals.

Heater power: a log fixes the heating rate P/C and the rise at full power P/A, not the wattage,
which is rarely stated. The lumped models hold power_w fixed (Marlin's default 40 W unless given)
and fit C, A and R: with the real wattage P', C and A scale by P'/P. ``FitResult.derived()`` gives
the power-free numbers.

Heat loss: the lumped models' loss is linear (Marlin's MPC model) unless ``loss`` asks for the
radiation-like term too (an effective area at emissivity 1, twin/plants.py ``Lumped``), fitted from
the linear fit's values; "auto" keeps whichever has the lower AIC (``fit_losses``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from tools.ident.fopdt import Fopdt
from tools.ident.lsq import Estimate, least_squares_fit
from tools.ident.response import model_response, zoh_response
from tools.ident.result import FitResult, aic
from tools.ident.segments import Segment
from twin.plants import MPC_HEATER_POWER_W, ONION_CARTRIDGE_HEAT_CAPACITY_J_K, V6_BLOCK_AREA_M2, Plant

MODELS = ("fopdt", "sopdt", "two_node", "three_node")
FITTED = {  # the parameters each model fits, besides initial_c, and ambient_c when it is not given
    "fopdt": ("gain_c", "time_constant_s", "delay_s"),
    "sopdt": ("gain_c", "lag1_s", "lag2_s", "delay_s"),
    "two_node": ("block_heat_capacity_j_k", "sensor_responsiveness_per_s", "ambient_xfer_w_k"),
    "three_node": ("block_heat_capacity_j_k", "cartridge_xfer_w_k", "sensor_responsiveness_per_s",
                   "ambient_xfer_w_k"),
}
HELD = {  # held fixed unless given: the log cannot tell them apart from the fitted ones
    "fopdt": {},
    "sopdt": {},
    "two_node": {"power_w": MPC_HEATER_POWER_W},
    # the fit is flat in the cartridge's capacity (python -m tools.validation.plant_check --fit refits 1..8 J/K)
    "three_node": {"power_w": MPC_HEATER_POWER_W, "cartridge_heat_capacity_j_k": ONION_CARTRIDGE_HEAT_CAPACITY_J_K},
}
LUMPED_MODELS = ("two_node", "three_node")
# The heat loss of the lumped models: "linear" A (Tb - Ta) alone; "radiating" adds Lumped's radiation
# term sigma eps area (Tb^4 - Ta^4) at emissivity 1, fitting the effective area; "auto" fits both
# and keeps the one of lower AIC (``information_criterion``).
LOSSES = ("linear", "radiating", "auto")
RADIATING_PARAM = "radiating_area_m2"
RADIATING_EMISSIVITY = 1.0  # held: the area absorbs it (emissivity times the onionheater block's own
# 14.7 cm^2 wanted 2.7 > 1, more than the block radiates: the term also stands for the heat break,
# the nozzle and convection's own rise with temperature, python -m tools.validation.plant_check --fit)
RADIATING_START_M2 = 2 * V6_BLOCK_AREA_M2  # twice an E3D V6 block's surface
# Up to 100 cm^2: about seven V6 blocks, more than a whole hot end's surface. From 0.01 cm^2: at 200 C
# a conductance of 1.5e-5 W/K, nothing beside a hot end's linear loss (0.07 W/K and up); the area is
# fitted as its logarithm, which on a plant without the term would run towards 0 for ever.
RADIATING_BOUNDS_M2 = (1e-6, 0.01)
# A record spanning less than this (C) cannot tell a radiating loss from a linear one: the radiating term is
# fitted only where the readings (and an M303 capture's relay target) span this much.
RADIATING_SPAN_C = 100.0

MAX_GUESS_DELAY_S = 60.0  # the start values try dead times up to this
AMBIENT_SLACK_SIGMAS = 4.0  # initial_c within this many noise sigmas of the first reading, ambient_c below the lowest
READING_STEP_C = 0.25  # plus the coarsest reading step of the logs here (the onionheater's thermocouple)
AMBIENT_BELOW_C = 30.0  # and ambient_c above the lowest reading minus this (a heat-up may start warm)
MAX_SENSOR_RESPONSIVENESS_PER_S = 10.0  # a sensor lag under 0.1 s: beyond every log here (0.3 s samples at best)


def fit_plants(make: Callable[..., Plant], start: dict[str, float], segments: Sequence[Segment],
               bounds: dict[str, tuple[float, float]] | None = None) -> Estimate:
    """Fit the parameters start names (within optional bounds) over segments at once;
    ``make(segment, **params)`` builds the plant for one segment from what the segment declares
    (its ambient, start state and fan)."""
    return least_squares_fit(lambda p: np.concatenate(
        [zoh_response(make(seg, **p), seg.t_s, seg.duty) - seg.temp_c for seg in segments]), start, bounds=bounds)



def _check_series(t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, n_params: int) -> None:
    if not (len(t_s) == len(temp_c) == len(duty)):
        raise ValueError(f"t_s, temp_c and duty differ in length ({len(t_s)}, {len(temp_c)}, {len(duty)})")
    if len(t_s) <= n_params + 1:
        raise ValueError(f"{len(t_s)} samples: too few to fit {n_params} parameters")
    if not (np.all(np.isfinite(t_s)) and np.all(np.isfinite(temp_c)) and np.all(np.isfinite(duty))):
        raise ValueError("t_s, temp_c and duty must be finite")
    if np.any(np.diff(t_s) <= 0):
        raise ValueError("t_s must increase")
    if np.any(duty < 0) or np.any(duty > 1):
        raise ValueError("duty must be within 0..1 of full power")


def reading_noise_c(temp_c: np.ndarray) -> float:
    """The readings' noise (standard deviation) from their second differences, robustly (MAD)."""
    d2 = np.diff(temp_c, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0)) if d2.size else 0.0


def _first_order_guess(t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, ambient_c: float) -> Fopdt:
    """Start values: dT/dt = (K u(t - L) - (T - ambient)) / tau by linear least squares on the
    sample-to-sample slopes (equation error), the duty 0 before the segment, for each dead time of
    whole samples; the best one."""
    dt = np.diff(t_s)
    slope = np.diff(temp_c) / dt
    rise = temp_c[:-1] - ambient_c
    best = None
    for shift in range(min(len(dt) // 4, int(MAX_GUESS_DELAY_S / np.median(dt))) + 1):
        x = np.column_stack((np.r_[np.zeros(shift), duty[: len(dt) - shift]], rise))
        coef, *_ = np.linalg.lstsq(x, slope, rcond=None)
        sse = float(np.sum(np.square(x @ coef - slope)))
        if coef[1] < 0 and coef[0] > 0 and (best is None or sse < best[0]):
            best = (sse, coef, float(t_s[shift] - t_s[0]))
    span_s = float(t_s[-1] - t_s[0])
    if best is None:  # no first-order shape in the slopes: rough numbers from the record itself
        return Fopdt(2.0 * max(float(np.ptp(temp_c)), 1.0) / max(float(duty.max()), 0.05), span_s / 3.0, 0.01 * span_s)
    _, (b, a), delay_s = best
    return Fopdt(float(-b / a), float(-1.0 / a), max(delay_s, float(np.median(dt)) / 2.0))


def start_values(model: str, guess: Fopdt, held: dict[str, float]) -> dict[str, float]:
    k, tau, delay = guess
    if model == "fopdt":
        return {"gain_c": k, "time_constant_s": tau, "delay_s": delay}
    if model == "sopdt":
        return {"gain_c": k, "lag1_s": tau, "lag2_s": delay / 2.0, "delay_s": delay / 2.0}
    loss_w_k = held["power_w"] / k
    start = {"block_heat_capacity_j_k": loss_w_k * tau, "ambient_xfer_w_k": loss_w_k,
             "sensor_responsiveness_per_s": min(1.0 / delay, MAX_SENSOR_RESPONSIVENESS_PER_S / 2)}
    if model == "three_node":  # the lag split between the cartridge contact and the sensor
        start["sensor_responsiveness_per_s"] = min(2.0 / delay, MAX_SENSOR_RESPONSIVENESS_PER_S / 2)
        start["cartridge_xfer_w_k"] = 2.0 * held["cartridge_heat_capacity_j_k"] / delay
    return {name: start[name] for name in FITTED[model]}


def _check_loss(model: str, loss: str) -> None:
    """ValueError for an unknown model or loss, or a nonlinear loss on a transfer function."""
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; valid: {', '.join(MODELS)}")
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; valid: {', '.join(LOSSES)}")
    if loss != "linear" and model not in LUMPED_MODELS:
        raise ValueError(f"loss {loss!r} needs a lumped model ({', '.join(LUMPED_MODELS)}): {model} has no heat-loss "
                         "term to make nonlinear")


def fit_model(model: str, t_s, temp_c, duty, ambient_c: float | None = None, *, power_w: float | None = None,
              fixed: dict[str, float] | None = None, start: dict[str, float] | None = None,
              observed: np.ndarray | None = None, loss: str = "linear",
              on_evaluation: Callable[[], None] | None = None) -> FitResult:
    """Fit a model to one segment: readings temp_c at t_s under the duty (0..1) held from each sample.

    model: "fopdt" (gain_c, time_constant_s, delay_s), "sopdt" (two lags, lag1_s >= lag2_s),
    "two_node" (Marlin's MPC model: block heat capacity, sensor responsiveness, ambient loss) or
    "three_node" (plus the heater cartridge's contact to the block: its lag and the sensor's can
    trade places, two near-equal optima); every one also fits initial_c, the temperature it starts
    at, near the first reading (one reading is noisy). ambient_c None: fitted too, within 30 C below
    the lowest reading and, give or take the readings' noise, not above it. power_w (lumped models,
    default 40 W) and other values in ``fixed`` are held; ``start`` overrides start values.
    observed (bool per sample, default all): the samples whose readings are compared; the others
    only carry a duty change (a relay's reconstructed switch instant).
    loss (lumped models): "linear", "radiating" (plus radiating_area_m2 at emissivity 1, within
    RADIATING_BOUNDS_M2) or "auto" (both, the lower AIC kept: ``fit_losses``).
    ValueError for an unusable series or option.
    """
    _check_loss(model, loss)
    if loss == "linear":
        return _fit_loss(model, "linear", t_s, temp_c, duty, ambient_c, power_w=power_w, fixed=fixed, start=start,
                         observed=observed, on_evaluation=on_evaluation)
    choice = fit_losses(model, t_s, temp_c, duty, ambient_c, power_w=power_w, fixed=fixed, start=start,
                        observed=observed)
    return choice.fits[choice.kept if loss == "auto" else "radiating"]


def _fit_loss(model: str, loss: str, t_s, temp_c, duty, ambient_c: float | None, *, power_w: float | None = None,
              fixed: dict[str, float] | None = None, start: dict[str, float] | None = None,
              observed: np.ndarray | None = None, on_evaluation: Callable[[], None] | None = None) -> FitResult:
    """``fit_model`` with one loss, "linear" or "radiating", from start values guessed or given."""
    radiating = loss == "radiating"
    fitted = FITTED[model] + ((RADIATING_PARAM,) if radiating else ())
    t_s, temp_c, duty = (np.asarray(a, dtype=float) for a in (t_s, temp_c, duty))
    _check_series(t_s, temp_c, duty, len(fitted) + 1 + (ambient_c is None))
    held = {**HELD[model], **({"emissivity": RADIATING_EMISSIVITY} if radiating else {})}
    unknown = (set(fixed or {}) | set(start or {})) - {*fitted, *held, "ambient_c", "initial_c"}
    if unknown:
        raise ValueError(f"{model} ({loss} loss) has no parameter {', '.join(sorted(unknown))}")
    held.update(fixed or {})
    if power_w is not None:
        held["power_w"] = float(power_w)
    if ambient_c is not None:
        held["ambient_c"] = float(ambient_c)
    # The start is the first reading and ambient at most the lowest (a heater cannot cool below it),
    # both give or take the readings' noise and resolution.
    seen = np.ones(len(t_s), bool) if observed is None else np.asarray(observed, bool)
    slack_c = AMBIENT_SLACK_SIGMAS * reading_noise_c(temp_c[seen]) + READING_STEP_C
    ambient_start_c = float(ambient_c if ambient_c is not None else temp_c.min())
    guess = _first_order_guess(t_s, temp_c, duty, ambient_start_c)
    first = {**start_values(model, guess, held), **({RADIATING_PARAM: RADIATING_START_M2} if radiating else {}),
             "initial_c": float(temp_c[0]), **({} if ambient_c is not None else {"ambient_c": ambient_start_c}),
             **(start or {})}
    first = {k: v for k, v in first.items() if k not in held}
    est = least_squares_fit(lambda p: (model_response(model, {**held, **p}, t_s, duty) - temp_c)[seen], first,
                            bounds={"ambient_c": (temp_c.min() - AMBIENT_BELOW_C, temp_c.min() + slack_c),
                                    "initial_c": (temp_c[0] - slack_c, temp_c[0] + slack_c),
                                    "delay_s": (0.0, math.inf),
                                    "sensor_responsiveness_per_s": (0.0, MAX_SENSOR_RESPONSIVENESS_PER_S),
                                    RADIATING_PARAM: RADIATING_BOUNDS_M2}, on_evaluation=on_evaluation)
    params, std = est.values, est.std_errors
    if model == "sopdt" and {"lag1_s", "lag2_s"} <= params.keys() and params["lag2_s"] > params["lag1_s"]:  # the two lags are interchangeable
        for d in (params, std):
            d["lag1_s"], d["lag2_s"] = d["lag2_s"], d["lag1_s"]
    return FitResult(model, params, std, held, est.residuals_c, loss)


class LossChoice(NamedTuple):
    """Both losses fitted to one segment, by loss name, and the name of the one of lower AIC."""

    fits: dict[str, FitResult]
    kept: str


def fit_losses(model: str, t_s, temp_c, duty, ambient_c: float | None = None, *,
               start: dict[str, float] | None = None, **options) -> LossChoice:
    """A lumped model fitted with the linear loss, then with the radiating one from the linear fit's
    values (a nested model: the radiating fit starts where the linear one ended, plus
    RADIATING_START_M2; ``start`` overrides both), ``fit_model``'s other options as given; kept: the
    lower AIC, which charges the radiating fit its extra parameter (``aic``)."""
    _check_loss(model, "auto")
    linear = _fit_loss(model, "linear", t_s, temp_c, duty, ambient_c,
                       start={k: v for k, v in (start or {}).items() if k != RADIATING_PARAM}, **options)
    radiating = _fit_loss(model, "radiating", t_s, temp_c, duty, ambient_c,
                          start={**linear.params, RADIATING_PARAM: RADIATING_START_M2, **(start or {})}, **options)
    fits = {"linear": linear, "radiating": radiating}
    return LossChoice(fits, min(fits, key=lambda name: aic(fits[name])))
