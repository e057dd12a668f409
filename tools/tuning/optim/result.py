"""The result every optimiser returns, and the evaluation ledger that builds it.

All optimisers share one contract: the objective takes a 2-D array (population x dims) and
returns one cost per row, so a population is evaluated as one batch of lanes (on the firmware
twin, one BatchTwin call); ``budget`` caps the number of rows evaluated. The ledger counts rows,
keeps the best point ever evaluated (an optimiser's own bookkeeping may lose it, e.g. Nelder-Mead
after a shrink) and the best cost after each iteration.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

BatchObjective = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class OptimResult:
    """Best point found, its cost, the best cost after each iteration, evaluations, wall time."""

    method: str
    x: np.ndarray
    cost: float
    history: np.ndarray
    evaluations: int
    wall_s: float


def batch_objective(scalar: Callable[[np.ndarray], float]) -> BatchObjective:
    """Wrap a function of one point (1-D array -> float) into a batch objective (rows -> costs)."""

    def batch(points: np.ndarray) -> np.ndarray:
        return np.array([float(scalar(row)) for row in points], dtype=float)

    return batch


def check_bounds(bounds: Sequence[Sequence[float]] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound arrays from [(lo, hi), ...]; ValueError unless finite and lo < hi."""
    table = np.asarray(bounds, dtype=float)
    if table.ndim != 2 or table.shape[1] != 2 or table.shape[0] == 0:
        raise ValueError(f"bounds must be a list of (low, high) pairs, got shape {table.shape}")
    low, high = table[:, 0].copy(), table[:, 1].copy()
    if not np.all(np.isfinite(table)) or np.any(low >= high):
        raise ValueError("bounds must be finite with low < high in every dimension")
    return low, high


class Ledger:
    """Counts evaluations against the budget and remembers the best point; builds the result."""

    def __init__(self, method: str, objective: BatchObjective, budget: int, dims: int) -> None:
        if budget < 1:
            raise ValueError(f"budget must be >= 1 objective evaluation, got {budget}")
        self.method = method
        self.objective = objective
        self.budget = int(budget)
        self.evaluations = 0
        self.best_x = np.full(dims, np.nan)
        self.best_cost = np.inf
        self.history: list[float] = []
        self._start_s = time.perf_counter()

    def __repr__(self) -> str:
        return (f"Ledger(method={self.method!r}, evaluations={self.evaluations} of {self.budget}, "
                f"best_cost={self.best_cost:.6g})")

    @property
    def remaining(self) -> int:
        return self.budget - self.evaluations

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Costs of the rows of points (NaN counts as +inf); raises if they exceed the budget."""
        points = np.atleast_2d(np.asarray(points, dtype=float))
        if points.shape[0] > self.remaining:
            raise RuntimeError(f"{self.method}: {points.shape[0]} evaluations exceed the {self.remaining} left")
        costs = np.asarray(self.objective(points), dtype=float).reshape(-1)
        if costs.shape[0] != points.shape[0]:
            raise ValueError(f"objective returned {costs.shape[0]} costs for {points.shape[0]} points")
        costs = np.where(np.isnan(costs), np.inf, costs)
        self.evaluations += points.shape[0]
        i = int(np.argmin(costs))
        if costs[i] < self.best_cost or self.evaluations == points.shape[0]:  # the first batch sets a point
            self.best_cost = float(costs[i])
            self.best_x = points[i].copy()
        return costs

    def end_iteration(self) -> None:
        """Record the best cost so far as one point of the convergence history."""
        self.history.append(self.best_cost)

    def result(self) -> OptimResult:
        return OptimResult(
            method=self.method,
            x=self.best_x,
            cost=self.best_cost,
            history=np.array(self.history),
            evaluations=self.evaluations,
            wall_s=time.perf_counter() - self._start_s,
        )
