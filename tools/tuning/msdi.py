"""The maximal-stability-degree method with iteration (MSDI) of seed 003 ("tuning the PID controller
to third-order models with a zero and time delay by the maximal stability degree method with
iteration"), for any rational model with dead time.

The loop: the parallel PID C(s) = kp + ki / s + kd s on G(s) = num(s) e^(-tau s) / den(s). Its
characteristic quasi-polynomial (seed 003 eq. (4), times s):

    D(s) = s den(s) + (kd s^2 + kp s + ki) num(s) e^(-tau s).

Placing a triple root at s = -J (the stability degree J), D(-J) = D'(-J) = D''(-J) = 0 (seed 003
eqs. (5)-(8)), is linear in (kp, ki, kd): one 3 x 3 system per J. The derivatives are exact: the
n-th derivative of p(s) e^(-tau s) is p_n(s) e^(-tau s) with p_(n+1) = p_n' - tau p_n.

Picking J. Seed 003 sweeps J and takes "the first maximum of the dependencies of the controller's
tuning parameters" (its Figure 3). Differentiating the three conditions along the sweep gives
M (kp', ki', kd') = (0, 0, D'''(-J)): the three curves have their maxima at the same J, where
D'''(-J) = 0 too, a quadruple root: the classic maximal stability degree. We take that first
smooth maximum of kp(J) (the curves also have poles where M is singular, seed 003's J = b1 / b0:
not maxima). Then we check what the method promises, that no root of D lies right of -J
(argument principle along Re s = -J): for a model with a zero slower than J (seed 003's
-1 / 163.4 s) it does not hold: a real closed-loop root sits just left of that zero, on the
root-locus branch that ends there (seed 003: at -0.00616 1/s, the loop's true stability degree),
and ``roots_right`` says so. Its residue is small (the zero nearly cancels it): a slow creep.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tools.tuning.gains import Gains
from tools.tuning.models import LinearModel

DERIVATIVES = 3  # D, D', D'' at -J: a triple root
J_GRID_POINTS = 3000  # the sweep's resolution: relative steps of 0.33 % over its 4.3 decades
ARGUMENT_POINTS_PER_RAD = 40  # the argument principle's grid: points per radian of the delay's rotation
DOMINANCE = 100.0  # the argument count's tail: the leading term this many times the rest
MAX_ARGUMENT_POINTS = 5_000_000  # memory bound of the argument count's grid
ROOT_SHIFT = 1e-3  # count roots right of -J (1 - ROOT_SHIFT): the triple root itself lies left of it


class Quasi(NamedTuple):
    """num(s) e^(-tau s) / den(s): polynomials highest power first (seed 003: b0 s + b1 and
    a0 s^3 + a1 s^2 + a2 s + a3), delay_s = tau. Gains come out in den/num's input units."""

    num: np.ndarray
    den: np.ndarray
    delay_s: float

    @classmethod
    def of(cls, model: LinearModel) -> Quasi:
        num, den = model.polynomials()
        return cls(np.asarray(num, float), np.asarray(den, float), model.delay_s)

    @classmethod
    def third_order_zero(cls, gain: float, lead_s: float, lags_s: tuple[float, float, float],
                         delay_s: float) -> Quasi:
        """Seed 003 eq. (1): k (T1 s + 1) e^(-tau s) / ((T2 s + 1)(T3 s + 1)(T4 s + 1))."""
        den = np.array([1.0])
        for lag in lags_s:
            den = np.polymul(den, [lag, 1.0])
        return cls(np.array([gain * lead_s, gain]), den, delay_s)


def _delayed_derivatives(poly: np.ndarray, delay_s: float, s: complex | float, count: int) -> np.ndarray:
    """d^n/ds^n [poly(s) e^(-tau s)] at s, n = 0..count-1."""
    out, p = [], np.asarray(poly, float)
    for _ in range(count):
        out.append(np.polyval(p, s) * np.exp(-delay_s * s))
        p = np.polysub(np.polyder(p), delay_s * p) if len(p) > 1 else -delay_s * p
    return np.array(out)


def _derivatives(poly: np.ndarray, s: float, count: int) -> np.ndarray:
    return _delayed_derivatives(poly, 0.0, s, count)


def terms(model: Quasi, gains: tuple[float, float, float], s: float, count: int = DERIVATIVES) -> np.ndarray:
    """(count, 4): the n-th derivatives at s of D's parts, s den(s) and kp s, ki, kd s^2 times
    num(s) e^(-tau s); each row sums to the n-th derivative of D at s."""
    polynomial = _derivatives(np.polymul([1.0, 0.0], model.den), s, count)
    columns = [_delayed_derivatives(np.polymul(power, model.num), model.delay_s, s, count)
               for power in ([1.0, 0.0], [1.0], [1.0, 0.0, 0.0])]  # kp s, ki, kd s^2 times num e^(-tau s)
    return np.column_stack([polynomial, *(g * c for g, c in zip(gains, columns, strict=True))])


def _system(model: Quasi, j: float) -> tuple[np.ndarray, np.ndarray]:
    """The 3 x 3 matrix M and right side r with M (kp, ki, kd) = r for a triple root at -j."""
    parts = terms(model, (1.0, 1.0, 1.0), -float(j))
    return parts[:, 1:], -parts[:, 0]


def gains_at(model: Quasi, j: float) -> tuple[float, float, float]:
    """(kp, ki, kd) that put a triple root of D at s = -j (in the model's input units per degC)."""
    kp, ki, kd = np.linalg.solve(*_system(model, j))
    return float(kp), float(ki), float(kd)


def characteristic(model: Quasi, gains: tuple[float, float, float], s: np.ndarray | complex) -> np.ndarray:
    """D(s) of the closed loop with parallel PID gains (kp, ki, kd)."""
    kp, ki, kd = gains
    s = np.asarray(s, dtype=complex)
    return (s * np.polyval(model.den, s)
            + (kd * s * s + kp * s + ki) * np.polyval(model.num, s) * np.exp(-model.delay_s * s))


def _dominance_frequency(model: Quasi, gains: tuple[float, float, float], sigma: float) -> float:
    """A frequency beyond which, on Re s = sigma, the leading term of s den(s) outweighs the rest of
    D DOMINANCE times (so arg D is that of s^n): doubled until the bound of the rest by the
    coefficients' magnitudes holds."""
    kp, ki, kd = gains
    rest_poly = np.abs(np.polymul([1.0, 0.0], model.den))[1:]
    loop_poly = np.abs(np.polymul([abs(kd), abs(kp), abs(ki)], model.num)) * math.exp(-sigma * model.delay_s)
    n = len(rest_poly)
    w = 1.0
    for _ in range(200):
        r = abs(sigma + 1j * w)
        if abs(model.den[0]) * r**n > DOMINANCE * (np.polyval(rest_poly, r) + np.polyval(loop_poly, r)):
            return w
        w *= 2.0
    raise ValueError("no frequency where the leading term dominates: not a retarded loop")


def is_retarded(model: Quasi) -> bool:
    """deg(s den) > deg(kd s^2 num): the delayed part has the lower degree (a FOPDT with a PID does not)."""
    return len(model.den) > len(model.num) + 1


def roots_right_of(model: Quasi, gains: tuple[float, float, float], sigma: float) -> int:
    """How many roots of D lie right of Re s = sigma: the argument principle along the line for a
    retarded quasi-polynomial (deg s den > deg s^2 num), Delta arg D(sigma + jw), w = 0..inf, is
    pi (n/2 - N) with n = deg(s den) (Stepan, Retarded Dynamical Systems, 1989, Theorem 2.19)."""
    n = len(model.den)  # deg(s den) = len(den)
    if not is_retarded(model):
        raise ValueError("the argument count needs deg(den) > deg(num) + 1 (a retarded loop)")
    w_max = _dominance_frequency(model, gains, sigma)
    points = int(max(20000, ARGUMENT_POINTS_PER_RAD * model.delay_s * w_max))
    if points > MAX_ARGUMENT_POINTS:
        raise ValueError(f"the argument count needs {points} points: gains or shift too large")
    w = np.r_[0.0, np.logspace(-8, math.log10(w_max), points)]
    arg = np.unwrap(np.angle(characteristic(model, gains, sigma + 1j * w)))
    # the tail beyond w_max: arg D -> arg (sigma + jw)^n -> n pi / 2
    total = arg[-1] - arg[0] + (n * math.pi / 2 - n * float(np.angle(sigma + 1j * w[-1])))
    return round(n / 2 - total / math.pi)


class MsdiResult(NamedTuple):
    """The chosen J, its gains (model input units per degC), the roots of D right of -J (0: J is
    the loop's stability degree; None for a neutral loop, where the count does not apply), and
    the sweep."""

    j: float
    gains: tuple[float, float, float]
    roots_right: int | None
    j_grid: np.ndarray
    curves: np.ndarray  # (len(j_grid), 3): kp, ki, kd


def sweep(model: Quasi, j_grid: np.ndarray) -> np.ndarray:
    """kp(J), ki(J), kd(J) over a grid of J (seed 003's Figure 3)."""
    return np.array([gains_at(model, j) for j in j_grid])


def first_maximum(model: Quasi, j_grid: np.ndarray, curves: np.ndarray, column: int = 0) -> float:
    """The J of the first local maximum of one gain's curve (kp by default), refined by bounded
    scalar minimisation between the grid points around it. The gains have poles where the system
    is singular (seed 003: J = b1 / b0, where its formulas divide by (b1 - b0 J)): a "maximum"
    next to a sign change of the determinant is such a pole, not a maximum. ValueError if none."""
    y = curves[:, column]
    det_sign = np.sign([np.linalg.det(_system(model, j)[0]) for j in j_grid])
    smooth = (det_sign[:-2] == det_sign[1:-1]) & (det_sign[1:-1] == det_sign[2:])
    peaks = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:]) & smooth) + 1
    if not peaks.size:
        raise ValueError("the gain curve has no maximum over the J range")
    i = int(peaks[0])
    import scipy.optimize
    best = scipy.optimize.minimize_scalar(lambda j: -gains_at(model, j)[column], bounds=(j_grid[i - 1], j_grid[i + 1]),
                                          method="bounded", options={"xatol": 1e-10 * j_grid[i]})
    return float(best.x)


def default_grid(model: Quasi) -> np.ndarray:
    """J from 1e-4 to 2 times the fastest rate of the model (its poles, 1/tau)."""
    rates = np.abs(np.roots(model.den))
    fast = max(float(rates.max()), 1.0 / model.delay_s if model.delay_s else 0.0)
    return np.logspace(math.log10(1e-4 * fast), math.log10(2.0 * fast), J_GRID_POINTS)


def msdi(model: Quasi, j_grid: np.ndarray | None = None) -> MsdiResult:
    """Seed 003's MSDI: sweep J, take the first maximum of kp(J), and count the roots right of -J."""
    grid = default_grid(model) if j_grid is None else np.asarray(j_grid, float)
    curves = sweep(model, grid)
    j = first_maximum(model, grid, curves)
    gains = gains_at(model, j)
    right = roots_right_of(model, gains, -j * (1.0 - ROOT_SHIFT)) if is_retarded(model) else None
    return MsdiResult(j, gains, right, grid, curves)


def msdi_gains(model: LinearModel) -> Gains:
    """The registry's MSDI rule: the model (input: heater duty) in, Gains out; ValueError when the
    chosen J gives negative gains."""
    result = msdi(Quasi.of(model))
    if min(result.gains) < 0:
        raise ValueError(f"MSDI at J = {result.j:.4g} gives negative gains {result.gains}")
    return Gains.from_duty(*result.gains)
