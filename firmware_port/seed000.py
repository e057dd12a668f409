"""The controllers of seed 000 (Lab Units 13 & 14, "Digital Twin for PID Controller Tuning (3D
Printer Application)"), as float laws, and one adaptor that puts any of them on the board.

Each law is a per-sample step in the seed's own units: ``step(error, setpoint) -> control signal``.
The seed's listings run them on their own loop (tools.seeds.seed000); ``SeedController`` runs the
same law on the firmware twin through the board's controller interface, the signal scaled so the
law's own saturation is full heater power (0..255).

- The fuzzy gain scheduler (section "How to Address These Challenges", first listing): error on
  [-10, 10] and its change on [-5, 5], three trapezoid/triangle sets each, five Mamdani rules giving
  Kp on [0, 10] and Ki, Kd on [0, 1]; a PID whose integral sums the error per sample, unclamped.
- Its Gaussian variant (second listing): Gaussian sets, two "anti-overshoot" rules, the integral
  clamped to +-50 and the signal to +-100.
- The adaptive PI-D (section "WE NEED TO IMPROVE FURTHER"): gains moved by |e|/setpoint, integral
  frozen above 1.5 x setpoint, derivative on the error, signal clipped to 0..1.5 x setpoint.
- The "ANFIS" (section "Implement Adaptive Techniques"): a ReLU network (e, de) -> (Kp, Ki, Kd)
  with weights trained elsewhere (this package imports no learning library).

The fuzzy schedulers are evaluated as scikit-fuzzy 0.5's control system evaluates the seed's
code, because the seed's printed numbers depend on it: every membership function is *sampled*
on its variable's 100-point universe and interpolated linearly (so at e = 0 on the 100-point
[-5, 5] grid, which has no point at 0, "negative" and "positive" still hold 0.0101: some rule
always fires); AND is min, a term's activation the max over its rules, implication clips the
sampled consequent, aggregation is max, and the crisp gain is the centroid of that piecewise-linear
set on the universe refined with each clip level's crossing points (scikit-fuzzy's
``defuzz(..., 'centroid')`` trapezoid moments).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from firmware_port.controller import OUTPUT_MAX
from firmware_port.marlin.constants import ISR_PERIOD_S, TICKS_PER_READING
from firmware_port.params import Param, ParamSpace
from firmware_port.thermistor import TEMP_ONE

BOARD_SAMPLE_S = float(TICKS_PER_READING * ISR_PERIOD_S)  # 0.16384 s between fresh readings
UNIVERSE_POINTS = 100  # seed 000: np.linspace(lo, hi, 100) for every fuzzy variable
ERROR_CLIP = 10.0  # seed 000: error clipped to its universe [-10, 10] before the fuzzy system
DELTA_CLIP = 5.0  # seed 000: change of error clipped to [-5, 5]
FUZZY_FULL_SCALE = 100.0  # seed 000 Gaussian variant's output saturation: +-100 (our full power)


# -- membership functions, sampled as scikit-fuzzy samples them --------------------------------

def _rise(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """0 below lo, 1 from hi, linear between; a vertical edge when lo == hi."""
    if lo == hi:
        return (x >= hi).astype(float)
    return np.clip((x - lo) / (hi - lo), 0.0, 1.0)


def _fall(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """1 up to lo, 0 from hi, linear between; a vertical edge when lo == hi."""
    if lo == hi:
        return (x <= lo).astype(float)
    return np.clip((hi - x) / (hi - lo), 0.0, 1.0)


def trapmf(x: np.ndarray, a: float, b: float, c: float, d: float) -> np.ndarray:
    """Trapezoid: feet a, d, shoulders b, c (scikit-fuzzy ``trapmf``)."""
    return np.minimum(_rise(x, a, b), _fall(x, c, d))


def trimf(x: np.ndarray, a: float, b: float, c: float) -> np.ndarray:
    """Triangle: feet a, c, peak b (scikit-fuzzy ``trimf``)."""
    return trapmf(x, a, b, b, c)


def gaussmf(x: np.ndarray, mean: float, sigma: float) -> np.ndarray:
    """exp(-(x - mean)^2 / (2 sigma^2)) (scikit-fuzzy ``gaussmf``)."""
    return np.exp(-((x - mean) ** 2) / (2.0 * sigma**2))


@dataclass(frozen=True)
class FuzzyVar:
    """A variable's universe and its terms' membership functions sampled on it."""

    universe: np.ndarray
    terms: dict[str, np.ndarray]

    def degree(self, term: str, value: float) -> float:
        """The sampled membership interpolated at ``value``, 0 outside the universe."""
        return float(np.interp(value, self.universe, self.terms[term], left=0.0, right=0.0))


def _crossings(x: np.ndarray, mf: np.ndarray, level: float) -> np.ndarray:
    """Where the piecewise-linear ``mf`` crosses ``level`` (the clip's corners)."""
    above = mf >= level
    i = np.flatnonzero(above[1:] != above[:-1])
    slope = mf[i + 1] - mf[i]
    return x[i] + (level - mf[i]) * (x[i + 1] - x[i]) / slope


def centroid(x: np.ndarray, mu: np.ndarray) -> float:
    """Centroid of the piecewise-linear set (x, mu): the trapezoids' moments over their areas."""
    x1, x2, y1, y2 = x[:-1], x[1:], mu[:-1], mu[1:]
    used = (y1 + y2) > 0.0
    x1, x2, y1, y2 = x1[used], x2[used], y1[used], y2[used]
    area = 0.5 * (x2 - x1) * (y1 + y2)
    moment = (2.0 / 3.0) * (x2 - x1) * (y2 + 0.5 * y1) / (y1 + y2) + x1
    return float(np.sum(moment * area) / max(float(np.sum(area)), float(np.finfo(float).eps)))


def defuzzify(output: FuzzyVar, cuts: dict[str, float]) -> float:
    """Clip each fired term at its activation, aggregate by max, take the centroid."""
    extra = [_crossings(output.universe, output.terms[t], cut) for t, cut in cuts.items() if cut > 0.0]
    x = np.union1d(output.universe, np.concatenate(extra)) if extra else output.universe
    mu = np.zeros_like(x)
    for term, cut in cuts.items():
        np.maximum(mu, np.minimum(cut, np.interp(x, output.universe, output.terms[term])), out=mu)
    return centroid(x, mu)


Rule = tuple[str, str, tuple[str, str, str]]  # (error term, change term, (Kp, Ki, Kd) terms)


@dataclass(frozen=True)
class FuzzyScheduler:
    """Mamdani gain scheduling (e, de) -> (Kp, Ki, Kd): min AND, max accumulation, centroid."""

    error: FuzzyVar
    delta: FuzzyVar
    outputs: tuple[FuzzyVar, FuzzyVar, FuzzyVar]
    rules: tuple[Rule, ...]

    def gains(self, error: float, delta: float) -> tuple[float, float, float]:
        cuts: list[dict[str, float]] = [{}, {}, {}]
        for err_term, delta_term, consequents in self.rules:
            strength = min(self.error.degree(err_term, error), self.delta.degree(delta_term, delta))
            for k, term in enumerate(consequents):
                cuts[k][term] = max(cuts[k].get(term, 0.0), strength)
        kp, ki, kd = (defuzzify(out, cut) for out, cut in zip(self.outputs, cuts, strict=True))
        return kp, ki, kd


def _var(lo: float, hi: float, **terms) -> FuzzyVar:
    x = np.linspace(lo, hi, UNIVERSE_POINTS)
    return FuzzyVar(x, {name: mf(x) for name, mf in terms.items()})


def _gain_vars(low, medium, high) -> tuple[FuzzyVar, FuzzyVar, FuzzyVar]:
    """Kp on [0, 10], Ki and Kd on [0, 1]; ``low(lo, hi)`` etc. give each term on that range."""
    return tuple(_var(0.0, top, low=low(top), medium=medium(top), high=high(top))  # type: ignore[return-value]
                 for top in (10.0, 1.0, 1.0))


# Seed 000, first fuzzy listing: "Define Fuzzy Rules" rule1..rule5.
TRIANGULAR_RULES: tuple[Rule, ...] = (
    ("negative", "negative", ("high", "low", "medium")),
    ("zero", "zero", ("medium", "medium", "low")),
    ("positive", "positive", ("low", "low", "medium")),
    ("negative", "positive", ("medium", "low", "low")),
    ("positive", "negative", ("medium", "low", "low")),
)
# Seed 000, Gaussian listing: rules 4 and 5 become "anti-overshoot" (Kp low, Kd high).
GAUSSIAN_RULES: tuple[Rule, ...] = TRIANGULAR_RULES[:3] + (
    ("positive", "negative", ("low", "low", "high")),
    ("negative", "positive", ("low", "low", "high")),
)


def triangular_scheduler() -> FuzzyScheduler:
    """The first listing's sets: trapezoids at the ends, a triangle in the middle."""
    def tri(a, b, c):
        return lambda x: trimf(x, a, b, c)
    return FuzzyScheduler(
        _var(-10.0, 10.0, negative=lambda x: trapmf(x, -10, -10, -5, 0), zero=tri(-5, 0, 5),
             positive=lambda x: trapmf(x, 0, 5, 10, 10)),
        _var(-5.0, 5.0, negative=lambda x: trapmf(x, -5, -5, -2.5, 0), zero=tri(-2.5, 0, 2.5),
             positive=lambda x: trapmf(x, 0, 2.5, 5, 5)),
        _gain_vars(lambda top: tri(0, 0, top / 2), lambda top: tri(0, top / 2, top),
                   lambda top: tri(top / 2, top, top)),
        TRIANGULAR_RULES,
    )


def gaussian_scheduler() -> FuzzyScheduler:
    """The second listing's Gaussian sets (means and sigmas as printed)."""
    def g(mean, sigma):
        return lambda x: gaussmf(x, mean, sigma)
    kp = _var(0.0, 10.0, low=g(2.5, 1), medium=g(5, 1.5), high=g(7.5, 1))
    kid = _var(0.0, 1.0, low=g(0.2, 0.1), medium=g(0.5, 0.1), high=g(0.8, 0.1))
    return FuzzyScheduler(
        _var(-10.0, 10.0, negative=g(-5, 2), zero=g(0, 1.5), positive=g(5, 2)),
        _var(-5.0, 5.0, negative=g(-2.5, 1), zero=g(0, 1), positive=g(2.5, 1)),
        (kp, kid, kid),
        GAUSSIAN_RULES,
    )


# -- the laws ------------------------------------------------------------------------------------

class Law(Protocol):
    """A seed-000 control law, one call per sample, in the seed's units."""

    def reset(self) -> None: ...

    def step(self, error: float, setpoint: float) -> float: ...

    def full_scale(self, setpoint: float) -> float: ...


@dataclass
class FuzzyPidLaw:
    """Seed 000's fuzzy-scheduled PID: u = Kp e + Ki sum(e) + Kd (e - e_prev), gains from the
    scheduler at the clipped (e, de); the integral sums e per sample (no dt, as printed).

    ``integral_limit`` / ``output_limit``: None in the first listing, 50 and 100 in the Gaussian one.
    The previous error starts at 0, so the first change of error is the whole step.
    """

    scheduler: FuzzyScheduler
    integral_limit: float | None = None
    output_limit: float | None = None
    gain_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)  # the scheduled gains' scaling factors (tuning)
    integral: float = 0.0
    prev_error: float = 0.0
    last_gains: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def reset(self) -> None:
        self.integral = self.prev_error = 0.0

    def step(self, error: float, setpoint: float) -> float:
        delta = error - self.prev_error
        scheduled = self.scheduler.gains(min(max(error, -ERROR_CLIP), ERROR_CLIP), min(max(delta, -DELTA_CLIP), DELTA_CLIP))
        kp, ki, kd = (g * s for g, s in zip(scheduled, self.gain_scale, strict=True))
        self.last_gains = (kp, ki, kd)
        self.integral += error
        if self.integral_limit is not None:
            self.integral = min(max(self.integral, -self.integral_limit), self.integral_limit)
        u = kp * error + ki * self.integral + kd * delta
        if self.output_limit is not None:
            u = min(max(u, -self.output_limit), self.output_limit)
        self.prev_error = error
        return u

    def full_scale(self, setpoint: float) -> float:
        return self.output_limit or FUZZY_FULL_SCALE


def fuzzy_law(gain_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> FuzzyPidLaw:
    """The first fuzzy listing: no integral clamp, no output clamp."""
    return FuzzyPidLaw(triangular_scheduler(), gain_scale=gain_scale)


def gaussian_law(gain_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> FuzzyPidLaw:
    """The Gaussian listing: integral clamped to +-50, output to +-100."""
    return FuzzyPidLaw(gaussian_scheduler(), integral_limit=50.0, output_limit=100.0, gain_scale=gain_scale)


# Seed 000, adaptive PI-D listing: Kp_init, Ki_init, Kd_init = 6.0, 1.0, 1.0; Kp_min 0.5, Ki_min 0.01
ADAPTIVE_INIT = (6.0, 1.0, 1.0)
ADAPTIVE_KP_MIN = 0.5
ADAPTIVE_KI_MIN = 0.01
ADAPTIVE_KI_SLOPE = 0.01  # Ki = min(Ki_max, Ki_min + 0.01 |e| / setpoint)
ADAPTIVE_LIMIT = 1.5  # integral frozen and output clipped at 1.5 x setpoint


@dataclass
class AdaptivePidLaw:
    """Seed 000's adaptive PI-D: Kp = max(0.5, Kp0 (1 - |e|/sp)), Ki = min(Ki0, 0.01 + 0.01 |e|/sp),
    Kd = Kd0 (1 - |e|/sp); the integral of e dt grows only while the output is below 1.5 sp;
    u = Kp e + Ki I - Kd de/dt, clipped to 0..1.5 sp. ``dt_s`` is the sample period."""

    dt_s: float
    kp_init: float = ADAPTIVE_INIT[0]
    ki_init: float = ADAPTIVE_INIT[1]
    kd_init: float = ADAPTIVE_INIT[2]
    integral: float = 0.0
    prev_error: float = 0.0

    def reset(self) -> None:
        self.integral = self.prev_error = 0.0

    def step(self, error: float, setpoint: float) -> float:
        share = abs(error) / setpoint
        kp = max(ADAPTIVE_KP_MIN, self.kp_init * (1.0 - share))
        ki = min(self.ki_init, ADAPTIVE_KI_MIN + ADAPTIVE_KI_SLOPE * share)
        kd = self.kd_init * (1.0 - share)
        if setpoint - error < ADAPTIVE_LIMIT * setpoint:  # the response, from the error
            self.integral += error * self.dt_s
        derivative = (error - self.prev_error) / self.dt_s
        self.prev_error = error
        u = kp * error + ki * self.integral - kd * derivative
        return min(max(u, 0.0), self.full_scale(setpoint))

    def full_scale(self, setpoint: float) -> float:
        return ADAPTIVE_LIMIT * setpoint


@dataclass(frozen=True)
class MlpWeights:
    """A ReLU network's layers as (W[n_in, n_out], b[n_out]); the last layer is linear."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]

    def __call__(self, error: float, delta: float) -> tuple[float, float, float]:
        h = np.array([error, delta], dtype=float)
        for k, (w, b) in enumerate(self.layers):
            h = h @ w + b
            if k < len(self.layers) - 1:
                h = np.maximum(h, 0.0)
        return float(h[0]), float(h[1]), float(h[2])


class GainMap(Protocol):
    """(e, de) -> (Kp, Ki, Kd): what the ANFIS law asks of its network."""

    def __call__(self, error: float, delta: float) -> tuple[float, float, float]: ...


@dataclass(frozen=True)
class TakagiSugeno:
    """A first-order Takagi-Sugeno system in Jang's ANFIS structure, (e, de) -> (Kp, Ki, Kd).

    Gaussian sets on each input (grid partition: rule (i, j) is set i of e AND set j of de, product
    t-norm), firing strengths normalised to sum 1, each rule's gains linear in (e, de, 1). This is
    what the seed's "ANFIS" names but does not build: its listing defines Gaussian sets on e and de
    (means -5, 0, 5, sigma 2) and never uses them; its network is a plain multilayer perceptron.
    """

    means: np.ndarray  # (2, n_sets): row 0 error, row 1 change of error
    sigmas: np.ndarray  # (2, n_sets)
    consequents: np.ndarray  # (n_sets * n_sets * 3, 3): per rule, rows for e, de, 1; columns Kp, Ki, Kd

    def design(self, error: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """Per sample, the normalised strengths times (e, de, 1): the layer the consequents multiply."""
        mu_e = np.exp(-((error[:, None] - self.means[0]) ** 2) / (2 * self.sigmas[0] ** 2))
        mu_d = np.exp(-((delta[:, None] - self.means[1]) ** 2) / (2 * self.sigmas[1] ** 2))
        w = (mu_e[:, :, None] * mu_d[:, None, :]).reshape(len(error), -1)
        w = w / np.maximum(w.sum(axis=1, keepdims=True), np.finfo(float).tiny)
        regressors = np.column_stack([error, delta, np.ones_like(error)])
        return (w[:, :, None] * regressors[:, None, :]).reshape(len(error), -1)

    def __call__(self, error: float, delta: float) -> tuple[float, float, float]:
        kp, ki, kd = self.design(np.array([error]), np.array([delta]))[0] @ self.consequents
        return float(kp), float(ki), float(kd)


@dataclass
class AnfisLaw:
    """Seed 000's "ANFIS" PID: gains from the network at the raw (e, de) (no input clip), then
    I = clip(I + integral_gain e, +-integral_limit), u = clip(Kp e + Ki I + Kd de, +-100).

    First listing: integral_gain 1, limit 50; the "refined" one: 0.5 ("faster anti-windup"), 30.
    """

    network: GainMap
    integral_gain: float = 1.0
    integral_limit: float = 50.0
    output_limit: float = FUZZY_FULL_SCALE
    integral: float = 0.0
    prev_error: float = 0.0
    last_gains: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))

    def reset(self) -> None:
        self.integral = self.prev_error = 0.0

    def step(self, error: float, setpoint: float) -> float:
        delta = error - self.prev_error
        kp, ki, kd = self.last_gains = self.network(error, delta)
        lim = self.integral_limit
        self.integral = min(max(self.integral + self.integral_gain * error, -lim), lim)
        self.prev_error = error
        u = kp * error + ki * self.integral + kd * delta
        return min(max(u, -self.output_limit), self.output_limit)

    def full_scale(self, setpoint: float) -> float:
        return self.output_limit


def mlp_from_arrays(coefs: Sequence[np.ndarray], intercepts: Sequence[np.ndarray]) -> MlpWeights:
    """Weights in scikit-learn's ``coefs_`` / ``intercepts_`` layout, copied as float64."""
    return MlpWeights(tuple((np.array(w, dtype=float), np.array(b, dtype=float))
                            for w, b in zip(coefs, intercepts, strict=True)))


# -- on the board ---------------------------------------------------------------------------------

class SeedController:
    """A seed-000 law on the board: error in degC from the reading, one law step per fresh reading,
    the signal scaled so that the law's own saturation (``full_scale``) is full power, 0..255.

    The laws were written for a loop where the signal may be negative (cooling); a heater cannot
    cool, so negative signals give 0. A non-finite signal (a diverging law) also gives 0.
    """

    check_interval_ms = None

    def __init__(self, law: Law):
        self.law = law

    def reset(self) -> None:
        self.law.reset()

    def __repr__(self) -> str:
        return f"SeedController({self.law!r})"

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        if target_c <= 0:
            self.law.reset()
            return 0
        u = self.law.step(target_c - temp_q5 / TEMP_ONE, float(target_c))
        counts = u / self.law.full_scale(float(target_c)) * OUTPUT_MAX
        if not math.isfinite(counts):
            return 0
        return int(min(max(math.floor(counts + 0.5), 0), OUTPUT_MAX))


def fuzzy_controller() -> SeedController:
    return SeedController(fuzzy_law())


def gaussian_controller() -> SeedController:
    return SeedController(gaussian_law())


def adaptive_controller() -> SeedController:
    return SeedController(AdaptivePidLaw(dt_s=BOARD_SAMPLE_S))


# Tuning: the schedulers' three output scaling factors, 1/20 to 20 on log scales (1 = the listing);
# the adaptive law's initial gains, 1/100 to 100 x the listing's, log scales.
GAIN_SCALE_BOUNDS = (0.05, 20.0)
ADAPTIVE_SPAN = 100.0


def _scale_params() -> tuple[Param, ...]:
    return tuple(Param(f"{name}_scale", "", *GAIN_SCALE_BOUNDS, 1.0, log=True) for name in ("kp", "ki", "kd"))


def fuzzy_space() -> ParamSpace:
    """seed000_fuzzy with its scheduled gains scaled by (kp_scale, ki_scale, kd_scale)."""
    return ParamSpace("seed000_fuzzy", _scale_params(), lambda *scale: SeedController(fuzzy_law(scale)))


def gaussian_space() -> ParamSpace:
    """seed000_gauss with its scheduled gains scaled by (kp_scale, ki_scale, kd_scale)."""
    return ParamSpace("seed000_gauss", _scale_params(), lambda *scale: SeedController(gaussian_law(scale)))


def adaptive_space() -> ParamSpace:
    """seed000_adaptive with its initial gains (law output units of the setpoint per degC) as parameters."""
    units = ("1/C", "1/(C s)", "s/C")  # law output (setpoint units) per degC, per degC s, per degC/s
    params = tuple(Param(name, unit, value / ADAPTIVE_SPAN, value * ADAPTIVE_SPAN, value, log=True)
                   for name, unit, value in zip(("kp_init", "ki_init", "kd_init"), units, ADAPTIVE_INIT))

    def factory(kp_init: float, ki_init: float, kd_init: float) -> SeedController:
        return SeedController(AdaptivePidLaw(dt_s=BOARD_SAMPLE_S, kp_init=kp_init, ki_init=ki_init, kd_init=kd_init))

    return ParamSpace("seed000_adaptive", params, factory)
