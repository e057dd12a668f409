"""The least-squares fitter every identification here uses: parameters as logarithms (positive,
relative steps) or as they are, optional bounds, standard errors from the Jacobian.

Uncertainty: standard errors are sqrt(diag((J^T J)^-1) s^2), J the Jacobian of the residuals at
the optimum and s^2 = (sum of squared residuals) / (n - p), or s^2 = 1 for residuals already
divided by their known standard deviation (``known_sigma``: as many residuals as parameters leave
no n - p to estimate it from). They hold for independent residuals. Real logs' residuals are
correlated (model error, quantised readings, a 1 Hz pwm), so read them as lower bounds, and compare
fits of different segments for the real spread.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

LINEAR_PARAMS = ("ambient_c", "initial_c", "delay_s")  # fitted as they are; the others as their logarithms
LOG_X_SCALE = 0.1  # least_squares x_scale of a logarithm (10 % steps); 1 C or 1 s for the linear ones
MAX_EVALUATIONS = 400  # residual evaluations: a segment that has not converged by then holds too little
UNDETERMINED = 1e-9  # a Jacobian column this small against the largest: the residuals ignore that parameter
MAX_LOG = 700.0  # exp() of a logarithm beyond this overflows: the optimiser is exploring, clip it


@dataclass(frozen=True)
class Estimate:
    """What least_squares_fit returns: the values, their standard errors and the residuals (model - log)."""

    values: dict[str, float]
    std_errors: dict[str, float]
    residuals_c: np.ndarray

    @property
    def rmse_c(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals_c))))

    @property
    def aic(self) -> float:
        return information_criterion(self.residuals_c, len(self.values))


def information_criterion(residuals_c: np.ndarray, n_params: int) -> float:
    """Akaike's information criterion of a least-squares fit, n ln(SSE / n) + 2 k (Akaike 1974, "A new
    look at the statistical model identification", IEEE TAC 19:716-723, for Gaussian residuals):
    lower is better; a parameter must buy more than a factor e^(2/n) of the squared error."""
    n = len(residuals_c)
    return float(n * math.log(max(float(np.sum(np.square(residuals_c))), 1e-300) / n) + 2 * n_params)


# --- the fitter ----------------------------------------------------------------------------------


def least_squares_fit(residuals: Callable[[dict[str, float]], np.ndarray], start: dict[str, float],
                      linear: Sequence[str] = LINEAR_PARAMS,
                      bounds: dict[str, tuple[float, float]] | None = None, known_sigma: bool = False,
                      on_evaluation: Callable[[], None] | None = None) -> Estimate:
    """Minimise sum(residuals(params)^2) from start, every parameter not in ``linear`` as its
    logarithm (positive, relative steps), within optional bounds (low, high) per parameter;
    standard errors from the Jacobian at the optimum (NaN at a bound, infinite if undetermined).
    known_sigma: the residuals are already divided by their standard deviations, so s^2 = 1, or the
    residuals' own SSE / (n - p) where that is larger (the stated deviations were too small).
    on_evaluation: called at each evaluation of the residuals (at most MAX_EVALUATIONS and the
    Jacobian's), for a progress bar."""
    names = list(start)
    is_log = np.array([name not in linear for name in names])

    def params(z: np.ndarray) -> dict[str, float]:
        values = np.where(is_log, np.exp(np.where(is_log, np.minimum(z, MAX_LOG), 0.0)), z)
        return dict(zip(names, values.tolist()))

    def internal(values) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return np.array([np.log(max(v, 0.0)) if log else v for v, log in zip(values, is_log)], dtype=float)

    limits = [(bounds or {}).get(name, (-math.inf, math.inf)) for name in names]
    import scipy.optimize  # here: a command's start-up needs no scipy
    from scipy.signal import BadCoefficients

    def evaluate(z: np.ndarray) -> np.ndarray:
        if on_evaluation is not None:
            on_evaluation()
        # Exploring far out: non-finite residuals, a rejected step; and scipy.signal's BadCoefficients where a lag
        # reaches 1e23 s (a transfer function's numerator / its leading coefficient below 1e-14): that model barely
        # responds, its residuals say so, and the fit's standard errors flag a lag the data leave open.
        with np.errstate(over="ignore", invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", BadCoefficients)
            return residuals(params(z))

    sol = scipy.optimize.least_squares(evaluate, internal(start.values()),
                                       x_scale=np.where(is_log, LOG_X_SCALE, 1.0), max_nfev=MAX_EVALUATIONS,
                                       bounds=(internal([lo for lo, _ in limits]), internal([hi for _, hi in limits])))
    values = params(sol.x)
    # A parameter stopped at a bound gets no standard error (NaN), one the residuals do not depend on
    # an infinite one; the others' come from their own columns of the Jacobian.
    column = np.linalg.norm(sol.jac, axis=0)
    free = (sol.active_mask == 0) & (column > UNDETERMINED * column.max())
    sigma_z = np.where(sol.active_mask == 0, np.inf, np.nan)
    jac = sol.jac[:, free]
    try:
        dof = len(sol.fun) - int(free.sum())
        s2 = float(sol.fun @ sol.fun) / max(dof, 1)
        cov = np.linalg.inv(jac.T @ jac) * (max(s2 if dof > 0 else 0.0, 1.0) if known_sigma else s2)
        sigma_z[free] = np.sqrt(np.abs(np.diag(cov)))
    except np.linalg.LinAlgError:  # the free ones are not determined apart
        pass
    with np.errstate(invalid="ignore"):  # an infinite error of a parameter at zero: NaN, as on a bound
        std = {n: float(values[n] * s if log else s) for n, s, log in zip(names, sigma_z, is_log)}  # delta method
    return Estimate(values, std, sol.fun.copy())

