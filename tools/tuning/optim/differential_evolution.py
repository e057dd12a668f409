"""Differential evolution (scipy.optimize.differential_evolution), under the shared contract.

The population is evaluated as one batch (``vectorized=True`` with ``updating='deferred'``, the
mode scipy requires for it), seeded from ``rng``. Defaults are scipy's (strategy best1bin,
mutation 0.5-1, recombination 0.7, Latin-hypercube start) except three, all so that the run
spends the budget it is given and no more: ``polish=False`` (the L-BFGS-B polish would evaluate
outside the budget), ``tol=0`` (run all generations, as the seeds' fixed-iteration comparisons
do) and a population of ``population`` points (default scipy's 15 per dimension, or half the budget
where the budget cannot pay for two generations of that: a rougher search, as a small budget asks,
for a family with many parameters). When every
initial cost is inf, scipy evaluates the first population again; a generation the budget cannot
pay for ends the run with the best point so far.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tools.tuning.optim.result import BatchObjective, Ledger, OptimResult, check_bounds

SCIPY_POPSIZE_PER_DIM = 15  # scipy.optimize.differential_evolution's default popsize multiplier
MIN_POPULATION = 5  # scipy's own floor on a population (max(5, popsize * N) members)


def minimize(
    objective: BatchObjective,
    bounds: Sequence[Sequence[float]] | np.ndarray,
    *,
    rng: np.random.Generator,
    budget: int,
    population: int | None = None,
    starts: np.ndarray | None = None,
    **options: Any,
) -> OptimResult:
    """DE with a population of ``population`` points, Latin-hypercube sampled but for up to a third of
    them taken from ``starts`` (known points, rows; clipped into the bounds: a warm start from the
    tuning rules); options go to scipy (e.g. strategy, mutation)."""
    low, high = check_bounds(bounds)
    size = min(SCIPY_POPSIZE_PER_DIM * low.size, budget // 2) if population is None else int(population)
    if size < MIN_POPULATION:
        if population is None:
            raise ValueError(f"budget {budget} is below two generations of DE's smallest population "
                             f"({2 * MIN_POPULATION} evaluations)")
        raise ValueError(f"population must be >= {MIN_POPULATION} for DE, got {size}")
    if budget < 2 * size:
        raise ValueError(f"budget {budget} is below two generations of DE ({2 * size} evaluations)")
    ledger = Ledger("de", objective, budget, low.size)
    from scipy.optimize import differential_evolution
    from scipy.stats import qmc
    start = qmc.scale(qmc.LatinHypercube(d=low.size, rng=rng).random(size), low, high)
    if starts is not None:
        known = np.clip(np.atleast_2d(np.asarray(starts, float)), low, high)[:size // 3]
        start[:len(known)] = known

    def batch(columns: np.ndarray) -> np.ndarray:
        if columns.shape[1] > ledger.remaining:
            raise _BudgetSpent
        return ledger(np.asarray(columns).T)

    settings = {"polish": False, "tol": 0.0, **options}
    try:
        differential_evolution(
            batch,
            list(zip(low, high, strict=True)),
            init=start,
            maxiter=budget // size - 1,
            vectorized=True,
            updating="deferred",
            rng=rng,
            callback=lambda intermediate_result: ledger.end_iteration(),
            **settings,
        )
    except _BudgetSpent:
        ledger.end_iteration()
    return ledger.result()


class _BudgetSpent(Exception):
    """scipy asked for more evaluations than the budget has left: stop with the best so far."""
