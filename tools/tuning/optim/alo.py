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
    here, a, b = walk_summary(t, t_max, n * dims, rng)
    return ((here - a) * (d - c).reshape(-1) / (b - a)).reshape(n, dims) + c


# Each random byte is 8 steps of a walk (its bits, most significant first: step = 2 bit - 1).
# For every byte value and every prefix length r = 0..8: the position after r steps and the
# lowest and highest positions reached in those r steps (0 included). A walk of t_max steps is
# then summarised from t_max / 8 bytes per walk with table look-ups, 8 times less work than
# summing single steps, with exactly the same distribution.
_STEPS = 2 * np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).astype(np.int16) - 1
_PREFIX = np.concatenate([np.zeros((256, 1), dtype=np.int16), np.cumsum(_STEPS, axis=1, dtype=np.int16)], axis=1)
_PREFIX_MIN = np.minimum.accumulate(_PREFIX, axis=1)
_PREFIX_MAX = np.maximum.accumulate(_PREFIX, axis=1)


def walk_summary(t: int, t_max: int, width: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """For ``width`` walks of t_max random +-1 steps (seed 002 eqs. 1-2) started at 0: the
    position after t steps, and the minimum and maximum over the whole walk."""
    blocks, last = -(-t_max // 8), t_max - 8 * (-(-t_max // 8) - 1)  # last: steps in the last byte
    codes = np.frombuffer(rng.bytes(blocks * width), dtype=np.uint8).reshape(blocks, width)
    parts = []
    for table in (_PREFIX, _PREFIX_MIN, _PREFIX_MAX):  # whole bytes by a 1-D look-up (fast), then the last
        values = np.take(table[:, 8], codes)
        values[-1] = np.take(table[:, last], codes[-1])
        parts.append(values)
    moved, lowest, highest = parts
    start = np.cumsum(moved, axis=0, dtype=np.int32) - moved
    block, into = divmod(t, 8)
    if block == blocks:  # t = t_max, a whole number of bytes
        block, into = blocks - 1, 8
    here = start[block] + np.take(_PREFIX[:, into], codes[block])
    return here, np.min(start + lowest, axis=0), np.max(start + highest, axis=0)


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
