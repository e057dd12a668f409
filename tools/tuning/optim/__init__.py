"""Optimisers under one contract: ``minimize(objective, bounds, *, rng, budget, **options)``; those in
``WARM_STARTS`` also take ``starts``, known points (rows) to put in their first population.

The objective maps a population (rows) to costs, so each generation is one batch of lanes on the
firmware twin; see result.py for the contract and the result type.
"""

from __future__ import annotations

from tools.tuning.optim import alo, differential_evolution, nelder_mead, ocalo, pso
from tools.tuning.optim.result import BatchObjective, OptimResult, batch_objective

METHODS = {
    "nm": nelder_mead.minimize,
    "de": differential_evolution.minimize,
    "pso": pso.minimize,
    "alo": alo.minimize,
    "ocalo": ocalo.minimize,
}
WARM_STARTS = frozenset({"de"})

__all__ = ["METHODS", "WARM_STARTS", "BatchObjective", "OptimResult", "batch_objective"]
