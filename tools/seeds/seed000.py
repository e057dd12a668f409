"""Seed 000 (Lab Units 13 & 14, "Digital Twin for PID Controller Tuning (3D Printer Application)")
re-run: its loops and metrics as its code computes them, a correct closed loop beside them, its
Nelder-Mead / PSO / DE tuning runs, its fuzzy, adaptive and "ANFIS" controllers, and the same
controllers on the firmware twin with a saturating heater.

What seed 000's code does differently from a correct closed loop (evidence: ``loop_evidence``):

1. The loop. With C = Nc/Dc (PID ``[Kd, Kp, Ki] / [1, 0]``) and G = Ng/Dg (``K wn^2 / (s^2 +
   2 zeta wn s + wn^2)``), the seed builds ``Nc Ng / (Nc Dg + Dc Ng)`` = C G / (C + G), not
   ``Nc Ng / (Dc Dg + Nc Ng)`` = C G / (1 + C G). With integral action C(0) is infinite, so its
   DC gain is G(0) = K = 5: the "closed loop" heads to 5 x the setpoint (250 degC for 50).
   Its "zero steady-state error" results are the response crossing 50 on its way up at t = 50 s.
2. The normalisation (Nelder-Mead and PSO listings): the plant numerator is divided by itself
   (K wn^2 = 0.05 becomes 1, so the plant gain is 100 C/W, not 5) and the PID numerator by its
   largest gain, so only the gains' ratios matter; ``Kp = 1`` and ``Kp = 10`` with the same ratios
   are the same loop, and the printed gains cannot be used on any plant.
3. The metrics. Settling time is the time of the *last sample outside* the 5 % band, and is
   reported as the end of the horizon whenever there is no overshoot (even if the response
   settled long before); rise time is the span between the first and the last samples inside
   10-90 % (a response that re-enters that band later "rises" again); steady-state error is the
   last sample only; the fuzzy listings' overshoot is signed (negative if the response never
   reaches the setpoint) and their rise time is the first sample at 90 %.
4. The controller listings (fuzzy, Gaussian fuzzy, ANFIS, adaptive) do not use the plant: they
   integrate the control signal, y[i] = y[i-1] + u dt (the adaptive one u dt / tau), a pure
   integrator with no gain, no lag and no heater limit; the signal may be negative (cooling)
   and, in the first fuzzy listing, unbounded. The refined ANFIS listing multiplies by
   t[i] - t[0] instead of dt, so its "plant" gain grows with time (500x by the end).
5. ``power_input`` is passed everywhere and used nowhere.

The project's default (``correct_closed_loop``, ``twin.metrics.step_metrics``, the firmware twin)
uses the correct loop and definitions; ``seed_closed_loop`` and ``seed_metrics`` exist to reproduce
the seed's numbers.
"""

from __future__ import annotations

import sys

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize
import scipy.signal

from firmware_port.controller import ControllerSpec
from firmware_port.seed000 import (
    BOARD_SAMPLE_S,
    AdaptivePidLaw,
    AnfisLaw,
    GainMap,
    Law,
    MlpWeights,
    SeedController,
    TakagiSugeno,
    fuzzy_law,
    gaussian_law,
    mlp_from_arrays,
)
from tools.seeds.report import (
    DIFFERS,
    PAPER,
    REPRODUCED,
    SMALL_BUDGET,
    Budget,
    Progress,
    SeedReport,
    Table,
    Verdict,
    no_progress,
    num,
    within,
)
from tools.tuning.gains import Gains
from twin.engine import Twin
from twin.metrics import StepMetrics
from twin.plants import SPECS

# Seed 000, section 4 ("Manual and Automated PID Tuning") simulation parameters.
PLANT_GAIN_C_W = 5.0  # K
TIME_CONSTANT_S = 10.0  # tau, wn = 1/tau
DAMPING = 0.7  # zeta
SETPOINT_C = 50.0
TIME_S = np.linspace(0.0, 50.0, 500)  # np.linspace(0, 50, 500): dt = 50/499 s
SETTLING_BAND = 0.05  # "abs(response - setpoint) > 0.05 * setpoint"
RISE_FROM, RISE_TO = 0.1, 0.9

# Tolerances of a reproduction. The seed prints two decimals: a deterministic listing re-run must
# agree to that rounding (0.005, plus float noise). Times are sample instants (50/499 s apart):
# an optimiser that lands on a marginally different point on another machine's BLAS may move a
# band crossing by one sample, so its times get one sample, its errors 0.05.
PRINT_TOL = 0.0051
SAMPLE_S = float(TIME_S[1] - TIME_S[0])
OPTIMISER_TOL = {"overshoot_pct": 0.05, "steady_state_error": 0.05,
                 "settling_time_s": SAMPLE_S + 1e-9, "rise_time_s": SAMPLE_S + 1e-9}


# -- the seed's loop and the correct one ---------------------------------------------------------

def plant_polynomials() -> tuple[list[float], list[float]]:
    """G(s) = K wn^2 / (s^2 + 2 zeta wn s + wn^2), as the seed writes it (wn = 1/tau)."""
    wn = 1.0 / TIME_CONSTANT_S
    return [PLANT_GAIN_C_W * wn**2], [1.0, 2 * DAMPING * wn, wn**2]


def seed_closed_loop(kp: float, ki: float, kd: float, *, normalise: bool) -> scipy.signal.lti:
    """The seed's ``pid_controller_response`` loop: Nc Ng / (Nc Dg + Dc Ng) = CG/(C+G).

    ``normalise``: the Nelder-Mead and PSO listings divide each polynomial by its largest
    coefficient first (the DE listing does not).
    """
    num, den = (np.asarray(p, dtype=float) for p in plant_polynomials())
    pid_num, pid_den = np.array([kd, kp, ki], dtype=float), np.array([1.0, 0.0])
    if normalise:
        num, den = num / np.max(num), den / np.max(den)
        pid_num, pid_den = pid_num / np.max(pid_num), pid_den / np.max(pid_den)
    system, pid = scipy.signal.lti(num, den), scipy.signal.lti(pid_num, pid_den)
    return scipy.signal.lti(np.polymul(pid.num, system.num),
                            np.polyadd(np.polymul(pid.num, system.den), np.polymul(pid.den, system.num)))


def correct_closed_loop(kp: float, ki: float, kd: float) -> scipy.signal.lti:
    """The unity-feedback loop CG/(1+CG) = Nc Ng / (Dc Dg + Nc Ng) on the same plant."""
    num, den = plant_polynomials()
    pid_num, pid_den = [kd, kp, ki], [1.0, 0.0]
    return scipy.signal.lti(np.polymul(pid_num, num), np.polyadd(np.polymul(pid_den, den), np.polymul(pid_num, num)))


def step_response(system: scipy.signal.lti, time_s: np.ndarray = TIME_S,
                  setpoint: float = SETPOINT_C) -> tuple[np.ndarray, np.ndarray]:
    """setpoint x the unit step response (``scipy.signal.step``), as the seed scales it."""
    t, y = scipy.signal.step(system, T=time_s)
    return t, setpoint * y


def seed_metrics(t: np.ndarray, y: np.ndarray, setpoint: float = SETPOINT_C) -> dict[str, float | None]:
    """The optimiser listings' ``calculate_metrics``, definitions as printed (see the module doc)."""
    peak = float(np.max(y))
    overshoot = peak - setpoint if peak > setpoint else 0.0
    outside = np.flatnonzero(np.abs(y - setpoint) > SETTLING_BAND * setpoint)
    settling = float(t[outside[-1]]) if peak > setpoint else float(t[-1])
    rising = np.flatnonzero((y >= RISE_FROM * setpoint) & (y <= RISE_TO * setpoint))
    return {
        "overshoot_pct": overshoot / setpoint * 100.0,
        "steady_state_error": abs(float(y[-1]) - setpoint),
        "settling_time_s": settling,
        "rise_time_s": float(t[rising[-1]] - t[rising[0]]) if len(rising) > 1 else None,
    }


def listing_metrics(t: np.ndarray, y: np.ndarray, setpoint: float = SETPOINT_C) -> dict[str, float | None]:
    """The fuzzy and ANFIS listings' metrics: signed overshoot, rise = first sample at 90 %,
    settling = the last sample outside the 5 % band."""
    reached = np.flatnonzero(y >= RISE_TO * setpoint)
    outside = np.flatnonzero(np.abs(y - setpoint) > SETTLING_BAND * setpoint)
    return {
        "overshoot_pct": (float(np.max(y)) - setpoint) / setpoint * 100.0,
        "steady_state_error": abs(float(y[-1]) - setpoint),
        "rise_time_s": float(t[reached[0]]) if reached.size else None,
        "settling_time_s": float(t[outside[-1]]) if outside.size else float(t[0]),
    }


def loop_evidence(kp: float, ki: float, kd: float, *, normalise: bool) -> dict[str, float]:
    """Why a seed-loop result cannot stand: its DC gain (final value / setpoint), the response's
    slope at the end of the horizon, and the correct loop's stability for the same gains."""
    seed = seed_closed_loop(kp, ki, kd, normalise=normalise)
    t, y = step_response(seed)
    correct = correct_closed_loop(kp, ki, kd)
    return {
        "seed_dc_gain": float(seed.num[-1] / seed.den[-1]),
        "seed_final_value_c": float(SETPOINT_C * seed.num[-1] / seed.den[-1]),
        "seed_slope_at_end_c_s": float((y[-1] - y[-2]) / (t[-1] - t[-2])),
        "correct_max_pole_real": float(np.max(np.real(correct.poles))),
    }


# -- the seed's cost functions ------------------------------------------------------------------

@dataclass(frozen=True)
class SeedCost:
    """``w_os overshoot + w_ss sse + w_st settling + w_reg sum(gain**reg_power)`` on the seed's loop."""

    overshoot: float
    steady_state: float
    settling: float
    regulariser: float
    reg_power: int
    normalise: bool

    def __call__(self, params: np.ndarray) -> float:
        kp, ki, kd = (float(p) for p in params)
        t, y = step_response(seed_closed_loop(kp, ki, kd, normalise=self.normalise))
        m = seed_metrics(t, y)
        overshoot_c = float(m["overshoot_pct"] or 0.0) * SETPOINT_C / 100.0
        reg = sum(abs(g) ** self.reg_power for g in (kp, ki, kd))
        return (self.overshoot * overshoot_c + self.steady_state * float(m["steady_state_error"] or 0.0)
                + self.settling * float(m["settling_time_s"] or 0.0) + self.regulariser * reg)


# Weights as printed: Nelder-Mead "cost = 10 overshoot + settling + 100 sse + 0.1 (Kp^2+Ki^2+Kd^2)",
# PSO "20 overshoot + 10 sse + 5 settling", DE "100 overshoot + 50 sse + 20 settling + 0.1 (Kp+Ki+Kd)".
NM_COST = SeedCost(10.0, 100.0, 1.0, 0.1, 2, normalise=True)
PSO_COST = SeedCost(20.0, 10.0, 5.0, 0.0, 1, normalise=True)
DE_COST = SeedCost(100.0, 50.0, 20.0, 0.1, 1, normalise=False)
NM_START = (1.0, 0.1, 0.01)
NM_BOUNDS = ((0.01, 10.0), (0.001, 1.0), (0.001, 1.0))
PSO_BOUNDS = ((0.1, 5.0), (0.001, 0.2), (0.001, 0.5))
DE_BOUNDS = ((0.05, 10.0), (0.0001, 1.0), (0.0001, 1.0))


def _pso(cost: Callable[[np.ndarray], float], bounds, rng: np.random.Generator, swarm_size: int = 30,
         max_iter: int = 100, omega: float = 0.5, phi_p: float = 0.5, phi_g: float = 0.5,
         min_step: float = 1e-8, min_func: float = 1e-8) -> tuple[np.ndarray, float]:
    """The PSO the seed calls (``pyswarm.pso`` defaults: w = c1 = c2 = 0.5; it stops when the swarm
    best improves by <= 1e-8 or moves <= 1e-8), vectorised over the swarm, positions clipped."""
    lb, ub = np.array(bounds, dtype=float).T
    span = ub - lb
    x = lb + rng.random((swarm_size, lb.size)) * span
    v = -span + rng.random((swarm_size, lb.size)) * 2 * span
    p, fp = x.copy(), np.array([cost(row) for row in x])
    g, fg = p[np.argmin(fp)].copy(), float(np.min(fp))
    for _ in range(max_iter):
        rp, rg = rng.random(x.shape), rng.random(x.shape)
        v = omega * v + phi_p * rp * (p - x) + phi_g * rg * (g - x)
        x = np.clip(x + v, lb, ub)
        fx = np.array([cost(row) for row in x])
        better = fx < fp
        p[better], fp[better] = x[better], fx[better]
        best = int(np.argmin(fp))
        if fp[best] < fg:
            step = float(np.linalg.norm(g - p[best]))
            improved = fg - float(fp[best])
            g, fg = p[best].copy(), float(fp[best])
            if improved <= min_func or step <= min_step:
                break
    return g, fg


# -- the controller listings' loops ----------------------------------------------------------------

def run_listing(law: Law, plant: str = "integrator", time_s: np.ndarray = TIME_S,
                setpoint: float = SETPOINT_C) -> np.ndarray:
    """A controller listing's loop: y[0] = 0, then y[i] = y[i-1] + u dt with u = law(sp - y[i-1]).

    ``plant``: "integrator" (fuzzy, ANFIS: dt = t[1] - t[0]), "integrator_tau" (adaptive PI-D:
    u dt / tau) or "elapsed" (refined ANFIS: u (t[i] - t[0]), its printed quirk).
    """
    law.reset()
    y = np.zeros_like(time_s)
    for i in range(1, len(time_s)):
        u = law.step(setpoint - y[i - 1], setpoint)
        if plant == "integrator":
            y[i] = y[i - 1] + u * (time_s[1] - time_s[0])
        elif plant == "integrator_tau":
            y[i] = y[i - 1] + u * (time_s[1] - time_s[0]) / TIME_CONSTANT_S
        elif plant == "elapsed":
            y[i] = y[i - 1] + u * (time_s[i] - time_s[0])
        else:
            raise ValueError(f"plant must be integrator, integrator_tau or elapsed, not {plant!r}")
    return y


# Seed 000's "ANFIS" listings: training inputs U(-10, 10)^2 (1000 x 2) after np.random.seed(42),
# heuristic labels, Dense ReLU layers, Adam, MSE, batch 32.
@dataclass(frozen=True)
class AnfisListing:
    hidden: tuple[int, ...]
    epochs: int
    labels: Callable[[np.ndarray, np.ndarray], np.ndarray]
    integral_gain: float
    integral_limit: float
    plant: str


ANFIS_LISTINGS = {
    "first": AnfisListing((16, 16), 50, lambda e, de: np.column_stack([2 + 0.1 * e, 0.01 * np.abs(e), 0.2 - 0.01 * de]),
                          1.0, 50.0, "integrator"),
    "refined": AnfisListing((32, 16), 100,
                            lambda e, de: np.column_stack([1.5 + 0.05 * e, 0.08 + 0.04 * np.abs(e), 0.2 - 0.005 * de]),
                            0.5, 30.0, "elapsed"),
}
ANFIS_DATA_SEED = 42  # the listing's np.random.seed(42)


def anfis_training_data(listing: str) -> tuple[np.ndarray, np.ndarray]:
    """The listing's data set, drawn exactly as it draws it (legacy seeded generator, seed 42)."""
    inputs = np.random.RandomState(ANFIS_DATA_SEED).uniform(-10, 10, (1000, 2))
    return inputs, ANFIS_LISTINGS[listing].labels(inputs[:, 0], inputs[:, 1])


def train_anfis(listing: str, rng: np.random.Generator) -> MlpWeights:
    """The "ANFIS" network trained with scikit-learn's MLPRegressor (the seed uses Keras; same
    layers, ReLU, Adam at lr 1e-3, batch 32, every epoch run); weights initialised from ``rng``."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.neural_network import MLPRegressor

    spec = ANFIS_LISTINGS[listing]
    inputs, labels = anfis_training_data(listing)
    model = MLPRegressor(hidden_layer_sizes=spec.hidden, activation="relu", solver="adam", alpha=0.0,
                         batch_size=32, learning_rate_init=1e-3, max_iter=spec.epochs, tol=0.0,
                         n_iter_no_change=spec.epochs, random_state=int(rng.integers(2**31)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(inputs, labels)
    return mlp_from_arrays(model.coefs_, model.intercepts_)


# The seed's unused ANFIS sets: Gaussians at -5, 0, 5 with sigma 2 on both inputs (its Step 1).
TS_INITIAL_MEANS = (-5.0, 0.0, 5.0)
TS_INITIAL_SIGMA = 2.0
TS_MAX_EVALUATIONS = 100  # of the residual; the labels' |e| kink is fitted to ~1e-3 by then


def train_takagi_sugeno(listing: str) -> TakagiSugeno:
    """A real ANFIS on the listing's data: Jang's hybrid learning in its variable-projection form,
    the linear consequents solved by least squares inside a Gauss-Newton fit of the Gaussian sets
    (scipy ``least_squares``), started from the seed's own sets. Deterministic (no random start)."""
    inputs, labels = anfis_training_data(listing)
    n = len(TS_INITIAL_MEANS)

    def unpack(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return params[: 2 * n].reshape(2, n), np.exp(params[2 * n:]).reshape(2, n)

    def solve(params: np.ndarray) -> tuple[TakagiSugeno, np.ndarray]:
        means, sigmas = unpack(params)
        x = TakagiSugeno(means, sigmas, np.zeros((n * n * 3, 3))).design(inputs[:, 0], inputs[:, 1])
        theta = np.linalg.lstsq(x, labels, rcond=None)[0]
        return TakagiSugeno(means, sigmas, theta), (x @ theta - labels).ravel()

    start = np.concatenate([np.tile(TS_INITIAL_MEANS, 2), np.full(2 * n, np.log(TS_INITIAL_SIGMA))])
    fit = scipy.optimize.least_squares(lambda p: solve(p)[1], start, max_nfev=TS_MAX_EVALUATIONS)
    return solve(fit.x)[0]


def anfis_label_radius(listing: str, elapsed_s: float) -> float:
    """Spectral radius of the listing's one-step error map near the setpoint, with the gains its
    network is trained to give there (the labels at e = de = 0), at loop time ``elapsed_s``.

    State (e, e_prev, I); per step I += g e, u = Kp e + Ki I + Kd (e - e_prev), e -= m u, with
    m = dt for the first listing and m = elapsed time for the refined one. Above 1 the loop cannot
    hold the setpoint: any residual error grows.
    """
    spec = ANFIS_LISTINGS[listing]
    kp, ki, kd = spec.labels(np.zeros(1), np.zeros(1))[0]
    m = elapsed_s if spec.plant == "elapsed" else SAMPLE_S
    g = spec.integral_gain
    step = np.array([[1.0 - m * (kp + ki * g + kd), m * kd, -m * ki],
                     [1.0, 0.0, 0.0],
                     [g, 0.0, 1.0]])
    return float(np.max(np.abs(np.linalg.eigvals(step))))


def anfis_law(listing: str, network: GainMap) -> AnfisLaw:
    spec = ANFIS_LISTINGS[listing]
    return AnfisLaw(network, integral_gain=spec.integral_gain, integral_limit=spec.integral_limit)


# -- reproductions ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Reproduction:
    """One printed result of seed 000 beside ours; ``tolerance`` per metric, absolute."""

    name: str
    source: str
    printed: dict[str, float]
    ours: dict[str, float | None]
    tolerance: dict[str, float]
    gains: tuple[float, float, float] | None = None
    evidence: dict[str, float] = field(default_factory=dict)

    def agrees(self, metric: str) -> bool:
        value = self.ours.get(metric)
        return value is not None and abs(value - self.printed[metric]) <= self.tolerance[metric]

    @property
    def reproduced(self) -> bool:
        return all(self.agrees(metric) for metric in self.printed)


PRINTED = {
    "fuzzy": ("fuzzy gain scheduling listing, 'Performance Metrics' printout and table",
              {"overshoot_pct": 12.33, "steady_state_error": 0.00, "rise_time_s": 0.40, "settling_time_s": 3.11}),
    "gauss": ("Gaussian fuzzy listing, printout and 'Achieved Value' table",
              {"overshoot_pct": 6.38, "steady_state_error": 0.00, "rise_time_s": 0.70, "settling_time_s": 1.90}),
    "adaptive": ("'Adaptive PI-D Controller Metrics' printout",
                 {"overshoot_pct": 0.92, "steady_state_error": 0.46, "settling_time_s": 9.62}),
    "anfis_first": ("first ANFIS listing, 'Performance Metrics' printout",
                    {"overshoot_pct": 0.53, "steady_state_error": 0.00, "rise_time_s": 0.70, "settling_time_s": 0.80}),
    "anfis_refined": ("refined ANFIS listing, printout and 'Final Performance Metrics'",
                      {"overshoot_pct": 5.09, "steady_state_error": 0.00, "rise_time_s": 0.70, "settling_time_s": 2.71}),
    "nm": ("Nelder-Mead listing ('Automating PID Tuning with Optimization'), metrics printout",
           {"overshoot_pct": 78.69, "steady_state_error": 0.00, "settling_time_s": 47.90, "rise_time_s": 25.45}),
    "pso": ("'PSO Optimized Performance Metrics' printout",
            {"overshoot_pct": 78.62, "steady_state_error": 0.74, "settling_time_s": 41.48, "rise_time_s": 31.06}),
    "de": ("'DE Optimized Performance Metrics' printout",
           {"overshoot_pct": 0.00, "steady_state_error": 0.00, "settling_time_s": 33.97, "rise_time_s": 29.06}),
}


def _reproduction(name: str, ours: dict, tolerance: dict[str, float] | float, **extra) -> Reproduction:
    source, printed = PRINTED[name]
    tol = tolerance if isinstance(tolerance, dict) else dict.fromkeys(printed, tolerance)
    return Reproduction(name, "seed 000, " + source, printed, {k: ours.get(k) for k in printed}, tol, **extra)


def reproduce_fuzzy(variant: str = "fuzzy") -> Reproduction:
    """The fuzzy listing ("fuzzy") or its Gaussian variant ("gauss") on the listing's loop."""
    law = {"fuzzy": fuzzy_law, "gauss": gaussian_law}[variant]()
    return _reproduction(variant, listing_metrics(TIME_S, run_listing(law)), PRINT_TOL)


def reproduce_adaptive() -> Reproduction:
    """The adaptive PI-D listing (Kp, Ki, Kd init 6, 1, 1) on its u dt / tau loop."""
    law = AdaptivePidLaw(dt_s=SAMPLE_S)
    y = run_listing(law, "integrator_tau")
    return _reproduction("adaptive", seed_metrics(TIME_S, y), PRINT_TOL)


def reproduce_anfis(listing: str, rng: np.random.Generator | None) -> Reproduction:
    """An ANFIS listing with our training: the seed says retraining gives other numbers ("select
    the one that created the best response"), so only the loop is reproduced, not the numbers;
    the tolerance is the printed rounding and ``reproduced`` says whether our training hit it.
    ``rng``: the seeded MLP as the seed's; None: a real Takagi-Sugeno ANFIS on the same data."""
    network = train_takagi_sugeno(listing) if rng is None else train_anfis(listing, rng)
    law = anfis_law(listing, network)
    y = run_listing(law, ANFIS_LISTINGS[listing].plant)
    return _reproduction(f"anfis_{listing}", listing_metrics(TIME_S, y), PRINT_TOL)


def _optimised(name: str, x: np.ndarray, normalise: bool, tol: dict[str, float]) -> Reproduction:
    kp, ki, kd = (float(v) for v in x)
    ours = seed_metrics(*step_response(seed_closed_loop(kp, ki, kd, normalise=normalise)))
    return _reproduction(name, ours, tol, gains=(kp, ki, kd), evidence=loop_evidence(kp, ki, kd, normalise=normalise))


def reproduce_nelder_mead() -> Reproduction:
    """``minimize(pid_cost, [1, 0.1, 0.01], bounds=..., method='Nelder-Mead')``: deterministic."""
    res = scipy.optimize.minimize(NM_COST, NM_START, bounds=NM_BOUNDS, method="Nelder-Mead")
    return _optimised("nm", res.x, True, OPTIMISER_TOL)


def reproduce_de(rng: np.random.Generator, popsize: int = 50, maxiter: int = 1000) -> Reproduction:
    """``differential_evolution(..., maxiter=1000, popsize=50, strategy='best1bin', tol=1e-6)``,
    seeded. The printed point is where the rising response crosses 50 exactly at t = 50 s."""
    res = scipy.optimize.differential_evolution(DE_COST, DE_BOUNDS, maxiter=maxiter, popsize=popsize,
                                                strategy="best1bin", tol=1e-6, rng=rng)
    return _optimised("de", res.x, False, OPTIMISER_TOL)


# The seed's PSO is unseeded (pyswarm draws from numpy's global state): its printed run cannot be
# replayed, only re-drawn. Our seeded run is compared with a tolerance wide enough for another
# draw of the same search (the swarm stops at the first improvement <= 1e-8, anywhere on the
# ridge where the normalised loop overshoots ~79 %): 1 %-point, 1 degC, 10 s.
PSO_TOL = {"overshoot_pct": 1.0, "steady_state_error": 1.0, "settling_time_s": 10.0, "rise_time_s": 10.0}


def reproduce_pso(rng: np.random.Generator) -> Reproduction:
    """``pso(pid_cost_pso, lb, ub, swarmsize=30, maxiter=100)`` with pyswarm's defaults, seeded."""
    x, _ = _pso(PSO_COST, PSO_BOUNDS, rng)
    return _optimised("pso", x, True, PSO_TOL)


# -- on the firmware twin ---------------------------------------------------------------------------

TWIN_PRESET = "seed000_second"  # 5/(100 s^2 + 14 s + 1) C/W, 40 W full scale (twin.plants)
TWIN_AMBIENT_C = 25.0
TWIN_DURATION_S = 300.0


def twin_step(controller: ControllerSpec | None = None, gains: tuple[float, float, float] | None = None,
              preset: str = TWIN_PRESET, duration_s: float = TWIN_DURATION_S) -> StepMetrics:
    """A SETPOINT_C step above ambient on the firmware twin (heater 0..full power): with an injected
    controller factory, or with Marlin's integer PID at the seed's gains (W per degC, converted to
    0..255 counts over the preset's full-scale power)."""
    if (controller is None) == (gains is None):
        raise ValueError("give exactly one of controller or gains")
    twin = Twin.create("pid", hotend=preset, ambient_c=TWIN_AMBIENT_C,
                       controllers=[controller] if controller is not None else ())
    if gains is not None:
        full_w = SPECS[preset].input_full_scale
        twin.hotend.gains = Gains.from_duty(*(g / full_w for g in gains)).firmware()
    twin.hotend.target_c = TWIN_AMBIENT_C + SETPOINT_C
    result = twin.run(duration_s).hotend.metrics(band_c=SETTLING_BAND * SETPOINT_C)
    assert not isinstance(result, list)
    return result


def twin_controllers(rng: np.random.Generator) -> dict[str, Callable[[], SeedController]]:
    """The seed's controllers as board controller factories (the ANFIS ones freshly trained)."""
    first, refined = train_anfis("first", rng), train_anfis("refined", rng)
    return {
        "fuzzy": lambda: SeedController(fuzzy_law()),
        "gauss": lambda: SeedController(gaussian_law()),
        "adaptive": lambda: SeedController(AdaptivePidLaw(dt_s=BOARD_SAMPLE_S)),
        "anfis_first": lambda: SeedController(anfis_law("first", first)),
        "anfis_refined": lambda: SeedController(anfis_law("refined", refined)),
    }


def twin_metric_row(m: StepMetrics) -> dict[str, float | None]:
    """The twin's step metrics under the seed's names (settling to the same 5 % band)."""
    return {"overshoot_pct": m.overshoot_pct, "steady_state_error": m.steady_state_error_c,
            "rise_time_s": m.rise_time_s, "settling_time_s": m.settling_time_5pct_s}


def twin_results(rng: np.random.Generator, gains: dict[str, tuple[float, float, float]],
                 duration_s: float = TWIN_DURATION_S,
                 progress: Progress = no_progress) -> dict[str, dict[str, float | None]]:
    """Every seed-000 controller, and Marlin's PID at each of ``gains`` (e.g. the optimisers'), on
    the firmware twin: metrics under the seed's names, same 5 % band, a saturating 40 W heater."""
    factories = twin_controllers(rng)
    progress("twin: the ANFIS networks trained")
    rows = {}
    for name, factory in factories.items():
        rows[name] = twin_metric_row(twin_step(factory, duration_s=duration_s))
        progress(f"twin: {name}")
    for name, g in gains.items():
        rows[name] = twin_metric_row(twin_step(gains=g, duration_s=duration_s))
        progress(f"twin: {name}")
    return rows


# -- the command's and the page's report ----------------------------------------------------------

RNG_SEED = 0  # root seed of every stochastic run (PSO, DE, the ANFIS networks' initialisation)
# DE: the printed run (popsize 50, 1000 generations, about 150 000 loop simulations) takes many
# minutes; the optimum it finds (the seed loop's rising response crossing 50 at t = 50 s) is found
# by a small seeded run as well. PSO runs the paper's 30 x 100 (it stops early) at every budget.
DE_SMALL = {"popsize": 10, "maxiter": 60}
DE_PAPER = {"popsize": 50, "maxiter": 1000}
TWIN_FULL_W = SPECS[TWIN_PRESET].input_full_scale
LOOPS = (
    "paper loop: the seed's own code, as printed: its CG/(C+G) closed loop for the optimisers "
    "(scipy.signal.step, 500 samples over 50 s), an integrator of u for the controller listings, its metric "
    "definitions (settling = the last sample outside 5 %); no firmware and no firmware delay",
    f"firmware twin: the `{TWIN_PRESET}` preset (5/(100 s^2 + 14 s + 1) C/W, a {TWIN_FULL_W:.0f} W heater that "
    "saturates), each controller on the board every 0.164 s (the optimisers' gains through Marlin's integer "
    "PID), 10-bit ADC, 7-bit soft PWM: the firmware's loop with its delays; the same 5 % band",
)


def de_options(budget: Budget) -> dict[str, int]:
    """DE's popsize and generations at a budget (N: the paper's popsize for N generations)."""
    if budget.iterations is not None:
        return {"popsize": DE_PAPER["popsize"], "maxiter": budget.iterations}
    return DE_PAPER if budget.name == PAPER else DE_SMALL


def steps(budget: Budget) -> int:
    """How many times ``report`` calls its progress: 8 listings, the ANFIS training, 8 twin runs."""
    return 8 + 1 + 5 + 3


@dataclass(frozen=True)
class Seed000Result:
    reproductions: tuple[Reproduction, ...]
    twin: dict[str, dict[str, float | None]]
    de_options: dict[str, int]


def run(budget: Budget = SMALL_BUDGET, progress: Progress = no_progress) -> Seed000Result:
    """Every listing in its own loop, then the controllers and the optimisers' gains on the twin."""
    jobs: list[tuple[str, Callable[[], Reproduction]]] = [
        ("fuzzy", lambda: reproduce_fuzzy("fuzzy")), ("gauss", lambda: reproduce_fuzzy("gauss")),
        ("adaptive", reproduce_adaptive),
        ("anfis first", lambda: reproduce_anfis("first", np.random.default_rng([RNG_SEED, 1]))),
        ("anfis refined", lambda: reproduce_anfis("refined", np.random.default_rng([RNG_SEED, 2]))),
        ("nelder-mead", reproduce_nelder_mead), ("pso", lambda: reproduce_pso(np.random.default_rng(RNG_SEED))),
        ("de", lambda: reproduce_de(np.random.default_rng(RNG_SEED), **de_options(budget))),
    ]
    reps = []
    for label, job in jobs:
        reps.append(job())
        progress(label)
    gains = {r.name: r.gains for r in reps if r.gains is not None}
    twin = twin_results(np.random.default_rng([RNG_SEED, 4]), gains, progress=progress)
    return Seed000Result(tuple(reps), twin, de_options(budget))


def _how(rep: Reproduction, de: dict[str, int]) -> str:
    """What our number is: which run, what is seeded or retrained, and the tolerance."""
    if rep.name.startswith("anfis"):
        return (f"the listing's loop with its network retrained (scikit-learn's MLPRegressor for its Keras network, "
                f"seeded from {RNG_SEED}); the seed says a retrained network gives other numbers")
    if rep.name == "pso":
        return (f"the seed's PSO is unseeded (pyswarm draws from numpy's global state), so its printed run cannot be "
                f"replayed: ours is one seeded draw ({RNG_SEED}) of the same search")
    if rep.name == "de":
        return (f"the listing's DE at popsize {de['popsize']} x {de['maxiter']} generations (printed: 50 x 1000), "
                "seeded; it lands on the printed crossing; nothing fitted")
    if rep.name == "nm":
        return "the listing's Nelder-Mead re-run (deterministic); nothing fitted"
    return "the listing re-run as printed; nothing fitted"


def _tolerance(rep: Reproduction, metric: str) -> str:
    tol = rep.tolerance[metric]
    if rep.name == "pso":
        tol = PRINT_TOL  # another draw is not a re-run: judged on the printed rounding
    if tol == PRINT_TOL:
        return "+-0.005 (the printed rounding)"
    return f"+-{tol:.3g} (one sample or 0.05: another CPU's optimum may move a crossing)"


def _agrees(rep: Reproduction, metric: str) -> bool:
    value = rep.ours.get(metric)
    tol = PRINT_TOL if rep.name == "pso" else rep.tolerance[metric]
    return within(value, rep.printed[metric], tol)


def verdicts(result: Seed000Result) -> list[Verdict]:
    rows = []
    for rep in result.reproductions:
        how = _how(rep, result.de_options)
        for metric, printed in rep.printed.items():
            agrees = _agrees(rep, metric)
            extra = ""
            if rep.name == "anfis_refined" and not agrees:
                radius = anfis_label_radius("refined", rep.printed["settling_time_s"])
                extra = (f"; the listing multiplies u by the elapsed time: at the printed settling time the one-step "
                         f"map near the setpoint has spectral radius {num(radius)} (> 1: it cannot hold the setpoint)")
            rows.append(Verdict(rep.name, metric, f"{printed:.2f}", num(rep.ours.get(metric)),
                                REPRODUCED if agrees else DIFFERS, f"{how}; {_tolerance(rep, metric)}{extra}"))
    return rows + [_settles_claim(rep) for rep in result.reproductions if rep.evidence]


def _settles_claim(rep: Reproduction) -> Verdict:
    """The tuned loop 'settles' at the setpoint with the printed steady-state error: where its own loop heads."""
    final_c = rep.evidence["seed_final_value_c"]
    holds = abs(final_c - SETPOINT_C) <= OPTIMISER_TOL["steady_state_error"]
    return Verdict(rep.name, "the tuned loop holds the setpoint", f"steady-state error "
                   f"{rep.printed['steady_state_error']:.2f} C", f"heads to {num(final_c, 1)} C",
                   REPRODUCED if holds else DIFFERS,
                   "the printed error is the last sample of 50 s; the seed's loop CG/(C+G) has the DC gain "
                   f"{num(rep.evidence['seed_dc_gain'], 1)}: at 50 s the response is passing the setpoint (slope "
                   f"{num(rep.evidence['seed_slope_at_end_c_s'], 3)} C/s) on its way to {num(final_c, 1)} C; the same "
                   "gains in a correct loop are in the notes", claim=True)


def _twin_why(rep: Reproduction) -> str:
    """Why the twin differs from the seed's loop, from the evidence ``loop_evidence`` computed."""
    ev = rep.evidence
    if ev:
        stable = "stable" if ev["correct_max_pole_real"] < 0 else "unstable"
        return (f"{rep.name}: the seed's loop is CG/(C+G): it heads to {num(ev['seed_final_value_c'], 1)} C, its slope "
                f"at the end of the horizon is {num(ev['seed_slope_at_end_c_s'], 3)} C/s; the same gains in a correct "
                f"loop are {stable} (largest pole real part {num(ev['correct_max_pole_real'], 4)} /s)")
    return (f"{rep.name}: the listing's 'plant' is a pure integrator of u (no gain, lag or heater limit); the twin's "
            "heater saturates")


def report(budget: Budget = SMALL_BUDGET, progress: Progress = no_progress) -> SeedReport[Seed000Result]:
    """Seed 000 re-run: the verdicts, the twin's table and why the twin differs."""
    result = run(budget, progress)
    de = result.de_options
    twin = Table(
        "Firmware twin (the same controllers and the optimisers' gains; no printed counterpart):",
        ("listing", "overshoot %", "steady-state error C", "rise s", "settling 5 % s"),
        tuple((r.name, *(num(result.twin[r.name][m]) for m in ("overshoot_pct", "steady_state_error",
                                                                 "rise_time_s", "settling_time_s")))
              for r in result.reproductions))
    return SeedReport(
        "000", "Digital Twin for PID Controller Tuning (lab units 13 and 14)",
        f"{budget}: DE popsize {de['popsize']} x {de['maxiter']} generations (the paper's 50 x 1000 with --budget "
        f"paper); PSO at the paper's 30 x 100; every stochastic run seeded from {RNG_SEED}",
        LOOPS, tuple(verdicts(result)), result, (twin,),
        tuple(_twin_why(r) for r in result.reproductions))



if __name__ == "__main__":  # python -m tools.seeds.seed000: the same as python -m tools.seeds 000
    from tools.seeds.command import main_for

    sys.exit(main_for("000", report, steps))
