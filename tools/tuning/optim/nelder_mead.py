"""Nelder-Mead (scipy.optimize.minimize, method 'Nelder-Mead'), under the shared contract.

Seed 000 tunes its PID with Nelder-Mead from a fixed start; here the start point is drawn from
``rng`` uniformly within the bounds, and scipy keeps every vertex inside them (``bounds=``).
scipy stops at ``maxfev`` evaluations exactly, so the budget is never exceeded.

The initial simplex is ours: scipy's default steps 5 % of each coordinate away from x0 and then
clips to the bounds, so a start near a bound yields a flat simplex that never leaves that bound
(seen here on a 3-D quadratic: 2 of 20 random starts stuck at the bound). We step
``SIMPLEX_STEP`` of the range from x0 towards the middle of the range, which always stays inside.
A reflection clipped at a bound can still flatten the simplex, so while budget remains and the
last run improved the best cost, Nelder-Mead restarts from the best point with a fresh simplex
(the usual restarted Nelder-Mead); on an ordinary run the restart confirms the optimum and stops.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tools.tuning.optim.result import BatchObjective, Ledger, OptimResult, check_bounds

SIMPLEX_STEP = 0.05  # fraction of each range: scipy's 5 % default step, taken on the range instead of x0


def initial_simplex(start: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """start plus one vertex per dimension, moved SIMPLEX_STEP of the range towards mid-range."""
    towards_middle = np.where(start <= (low + high) / 2.0, 1.0, -1.0)
    vertices = np.tile(start, (start.size + 1, 1))
    vertices[1:] += np.diag(towards_middle * SIMPLEX_STEP * (high - low))
    return vertices


def minimize(
    objective: BatchObjective,
    bounds: Sequence[Sequence[float]] | np.ndarray,
    *,
    rng: np.random.Generator,
    budget: int,
    x0: Sequence[float] | None = None,
    **options: Any,
) -> OptimResult:
    """Restarted Nelder-Mead from x0 (default: uniform in bounds from rng); options go to scipy's ``options``."""
    low, high = check_bounds(bounds)
    ledger = Ledger("nm", objective, budget, low.size)
    start = rng.uniform(low, high) if x0 is None else np.clip(np.asarray(x0, dtype=float), low, high)

    def scalar(x: np.ndarray) -> float:
        return float(ledger(x[None, :])[0])

    from scipy.optimize import minimize as scipy_minimize

    improved = True
    while improved and ledger.remaining > low.size + 1:
        previous_cost = ledger.best_cost
        with np.errstate(invalid="ignore"):  # scipy's tolerance test subtracts inf - inf on an all-inf simplex
            scipy_minimize(
                scalar,
                start,
                method="Nelder-Mead",
                bounds=list(zip(low, high, strict=True)),
                callback=lambda intermediate_result: ledger.end_iteration(),
                options={"initial_simplex": initial_simplex(start, low, high), **options, "maxfev": ledger.remaining},
            )
        start = ledger.best_x
        improved = ledger.best_cost < previous_cost
    if not ledger.history or ledger.history[-1] != ledger.best_cost:
        ledger.end_iteration()
    return ledger.result()
