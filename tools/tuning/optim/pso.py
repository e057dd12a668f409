"""Particle swarm optimisation: a short vectorised global-best PSO with seed 000's coefficients.

Seed 000 (its PSO section) calls the ``pyswarm`` package's ``pso(..., swarmsize=30,
maxiter=100)`` with the package's default coefficients: inertia omega = 0.5, cognitive
phip = 0.5, social phig = 0.5, velocities started uniform in +-(ub - lb), positions clipped to
the bounds after each move. pyswarm draws from numpy's global random state and evaluates one
particle at a time, and pyswarms (the other maintained PSO library) also uses the global state,
so neither can take our seeded Generator or a batch objective: this is the same update,
v = w v + c1 r1 (p_best - x) + c2 r2 (g_best - x), x = x + v (seed 000's PSO equations), with the
swarm evaluated as one batch and the global best updated once per iteration. pyswarm's early
stops (minstep, minfunc) are left out: the run spends its budget, as the seeds' comparisons do.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tools.tuning.optim.result import BatchObjective, Ledger, OptimResult, check_bounds

INERTIA = 0.5  # pyswarm.pso default omega (the library seed 000 uses)
COGNITIVE = 0.5  # pyswarm.pso default phip
SOCIAL = 0.5  # pyswarm.pso default phig
SWARM_SIZE = 30  # seed 000's swarmsize


def minimize(
    objective: BatchObjective,
    bounds: Sequence[Sequence[float]] | np.ndarray,
    *,
    rng: np.random.Generator,
    budget: int,
    population: int = SWARM_SIZE,
    inertia: float = INERTIA,
    cognitive: float = COGNITIVE,
    social: float = SOCIAL,
) -> OptimResult:
    """Global-best PSO; iterations = budget // population - 1 after the initial swarm."""
    low, high = check_bounds(bounds)
    if population < 2 or budget < population:
        raise ValueError(f"PSO needs population >= 2 and budget >= population, got {population}, {budget}")
    ledger = Ledger("pso", objective, budget, low.size)
    span = high - low
    x = low + span * rng.random((population, low.size))
    v = span * rng.uniform(-1.0, 1.0, (population, low.size))
    p, fp = x.copy(), ledger(x)
    ledger.end_iteration()
    while ledger.remaining >= population:
        g = p[int(np.argmin(fp))]
        r_p, r_g = rng.random((2, population, low.size))
        v = inertia * v + cognitive * r_p * (p - x) + social * r_g * (g - x)
        x = np.clip(x + v, low, high)
        fx = ledger(x)
        better = fx < fp
        p[better], fp[better] = x[better], fx[better]
        ledger.end_iteration()
    return ledger.result()
