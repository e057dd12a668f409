"""Ant-lion optimiser (ALO), as seed 002 (the OCALO 3D-printing PID paper) restates it.

Seed 002, section 2.1, after the ALO paper it cites (Mirjalili, "The Ant Lion Optimizer",
Adv. Eng. Softw. 83, 2015):
- an ant walks at random: X = [0, cumsum(2 r(t_1) - 1), ..., cumsum(2 r(t_n) - 1)] with
  r(t) = 1 if rand > 0.5 else 0 (seed 002 eqs. 1-2), one walk of t_max steps per dimension;
- the walk is min-max normalised into the trap of an ant-lion, X' = (X - a)(d - c)/(b - a) + c,
  a, b the walk's min and max, and the ant takes the walk's value at the current iteration t;
- the trap [c, d] is the search range shrunk by the ratio I and moved onto the ant-lion (each
  bound added to or subtracted from its position with probability 1/2), with
  I = 1 + 10^w t / t_max, w = 2, 3, 4, 5, 6 once t exceeds 10, 50, 75, 90, 95 % of t_max
  (the ALO paper's sliding of ants into the trap; I = 1 before 10 %);
- each ant walks around an ant-lion picked by roulette wheel (R_A) and around the elite (R_E)
  and lands at (R_A + R_E) / 2 (seed 002 eq. 4);
- an ant-lion takes an ant's place when the ant is fitter (eq. 3): ants and ant-lions are
  pooled, the fittest ``population`` stay ant-lions, and the elite is the best ever.

Roulette weights: the ALO paper's code weights ant-lions by 1/cost, which is undefined for costs
<= 0 (F8, F16-F23 and any cost that can reach 0); we weight by rank (the best of N ant-lions
N, the worst 1), which keeps its preference for fitter ant-lions on any cost scale.

``search`` runs the loop for a given initial population and ant update, so OCALO reuses it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from tools.tuning.optim.result import BatchObjective, Ledger, OptimResult, check_bounds

POPULATION = 50  # seed 002's population for its benchmark runs
I_STAGES = ((0.95, 6), (0.9, 5), (0.75, 4), (0.5, 3), (0.1, 2))  # (fraction of t_max, w): ALO paper

# Where an ant lands from its walks around the roulette ant-lion (R_A) and the elite (R_E).
AntUpdate = Callable[[np.ndarray, np.ndarray, int, int, np.random.Generator], np.ndarray]


def shrink_ratio(t: int, t_max: int) -> float:
    """The ALO paper's I: 1 + 10^w t / t_max, w stepping up with progress (1 before 10 %)."""
    for fraction, w in I_STAGES:
        if t > fraction * t_max:
            return 1.0 + 10.0**w * t / t_max
    return 1.0


def random_walks(
    centres: np.ndarray, low: np.ndarray, high: np.ndarray, t: int, t_max: int, rng: np.random.Generator
) -> np.ndarray:
    """Position at step t of one normalised random walk per centre (row) and dimension."""
    n, dims = centres.shape
    ratio = shrink_ratio(t, t_max)
    flip_low, flip_high = rng.random((2, n, 1)) < 0.5
    c = np.where(flip_low, low / ratio, -low / ratio) + centres
    d = np.where(flip_high, -high / ratio, high / ratio) + centres
    sums = np.int16 if t_max <= np.iinfo(np.int16).max else np.int32  # int16 cumsum: twice as fast
    walks = np.cumsum(_unit_steps(t_max, n * dims, rng), axis=0, dtype=sums)  # time-major: fastest
    a = np.minimum(walks.min(axis=0), 0).reshape(n, dims)  # the walk starts at 0 (eq. 1)
    b = np.maximum(walks.max(axis=0), 0).reshape(n, dims)
    here = walks[t - 1].reshape(n, dims)  # t >= 1: the walk after t steps
    return (here - a) * (d - c) / (b - a) + c


def _unit_steps(count: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """(count, width) steps of +-1 with probability 1/2 each (2 r(t) - 1 of eq. 2), from random bits."""
    size = count * width
    bits = np.unpackbits(np.frombuffer(rng.bytes(-(-size // 8)), dtype=np.uint8))[:size]
    return (bits.view(np.int8) * 2 - 1).reshape(count, width)


def roulette(n_antlions: int, n_ants: int, rng: np.random.Generator) -> np.ndarray:
    """Indices into ant-lions sorted best first, drawn with rank weights N, N-1, ..., 1."""
    weights = np.arange(n_antlions, 0, -1, dtype=float)
    return rng.choice(n_antlions, size=n_ants, p=weights / weights.sum())


def average_update(r_a: np.ndarray, r_e: np.ndarray, t: int, t_max: int, rng: np.random.Generator) -> np.ndarray:
    """ALO's ant position: the mean of the two walks (seed 002 eq. 4)."""
    return (r_a + r_e) / 2.0


def search(
    ledger: Ledger,
    antlions: np.ndarray,
    costs: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    rng: np.random.Generator,
    update: AntUpdate,
) -> OptimResult:
    """Iterate ants and ant-lions until the budget cannot pay for another population of ants."""
    n = antlions.shape[0]
    order = np.argsort(costs, kind="stable")
    antlions, costs = antlions[order], costs[order]
    t_max = max(1, ledger.remaining // n)
    for t in range(1, t_max + 1):
        picked = antlions[roulette(n, n, rng)]
        r_a = random_walks(picked, low, high, t, t_max, rng)
        r_e = random_walks(np.broadcast_to(antlions[0], picked.shape), low, high, t, t_max, rng)
        ants = np.clip(update(r_a, r_e, t, t_max, rng), low, high)
        ant_costs = ledger(ants)
        pool = np.concatenate([antlions, ants])
        pool_costs = np.concatenate([costs, ant_costs])
        order = np.argsort(pool_costs, kind="stable")[:n]  # the elite stays first: it is the pool's best
        antlions, costs = pool[order], pool_costs[order]
        ledger.end_iteration()
    return ledger.result()


def minimize(
    objective: BatchObjective,
    bounds: Sequence[Sequence[float]] | np.ndarray,
    *,
    rng: np.random.Generator,
    budget: int,
    population: int = POPULATION,
) -> OptimResult:
    """ALO with uniform random initial ant-lions; t_max = budget // population - 1 iterations."""
    low, high = check_bounds(bounds)
    if population < 2 or budget < 2 * population:
        raise ValueError(f"ALO needs population >= 2 and budget >= 2 x population, got {population}, {budget}")
    ledger = Ledger("alo", objective, budget, low.size)
    antlions = low + (high - low) * rng.random((population, low.size))
    costs = ledger(antlions)
    ledger.end_iteration()
    return search(ledger, antlions, costs, low, high, rng, average_update)
