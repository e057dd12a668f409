"""Optimisers under one contract: determinism, budget, bounds, convergence on a convex bowl."""

from __future__ import annotations

import numpy as np
import pytest

from tools.tuning.optim import METHODS, WARM_STARTS, batch_objective
from tools.tuning.optim.alo import random_walks, shrink_ratio, walk_summary
from tools.tuning.optim.ocalo import chaotic_population, cosine_update, tent_logistic_cotangent
from tools.tuning.optim.result import check_bounds

CENTRE = np.array([1.5, -2.0, 0.5])  # off the origin on purpose (OCALO pulls towards the origin)
WEIGHTS = np.array([1.0, 4.0, 9.0])
BOUNDS = [(-5.0, 5.0)] * 3
BUDGET = 3000
# Largest |x - CENTRE| accepted after BUDGET evaluations. Measured over 100 seeds (20 for OCALO):
# NM 8e-5, DE 3e-6, PSO 3e-13, ALO 3e-5, OCALO 0.13 (its cosine factors shrink the ants' steps
# towards the origin late in the run, so it polishes poorly off the origin); each bound leaves
# about a factor 4 of margin.
TOLERANCE = {"nm": 1e-3, "de": 1e-4, "pso": 1e-6, "alo": 1e-3, "ocalo": 0.5}


def bowl(points: np.ndarray) -> np.ndarray:
    return np.sum(WEIGHTS * (points - CENTRE) ** 2, axis=1)


def run(method: str, seed: int, objective=bowl, budget: int = BUDGET):
    return METHODS[method](objective, BOUNDS, rng=np.random.default_rng(seed), budget=budget)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_same_seed_same_result(method: str) -> None:
    first, again, other = run(method, 7), run(method, 7), run(method, 8)
    # Two runs in one process on one CPU: the same arithmetic in the same order, so equal exactly.
    np.testing.assert_array_equal(first.x, again.x)
    np.testing.assert_array_equal(first.history, again.history)
    assert first.evaluations == again.evaluations
    assert not np.array_equal(first.x, other.x)  # the seed is really used


@pytest.mark.parametrize("method", sorted(METHODS))
def test_finds_the_minimum_of_a_convex_bowl(method: str) -> None:
    for seed in range(3):
        result = run(method, seed)
        assert np.max(np.abs(result.x - CENTRE)) < TOLERANCE[method], (seed, result.x)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_budget_bounds_history_and_best_point(method: str) -> None:
    seen: list[np.ndarray] = []

    def recording(points: np.ndarray) -> np.ndarray:
        seen.append(np.array(points))
        return bowl(points)

    budget = 1000
    result = run(method, 3, recording, budget)
    points = np.concatenate(seen)
    assert result.evaluations == points.shape[0] <= budget
    low, high = check_bounds(BOUNDS)
    assert np.all(points >= low) and np.all(points <= high)
    assert np.all(np.diff(result.history) <= 0)  # best cost so far never gets worse
    assert result.history[-1] == result.cost
    assert result.cost == pytest.approx(float(bowl(result.x[None, :])[0]), rel=1e-12)
    assert result.cost == pytest.approx(float(np.min(bowl(points))), rel=1e-12)
    assert result.wall_s >= 0 and result.method == method


def test_batch_objective_wraps_a_scalar_function() -> None:
    scalar_calls: list[float] = []

    def scalar(x: np.ndarray) -> float:
        scalar_calls.append(float(x[0]))
        return float(np.sum(WEIGHTS * (x - CENTRE) ** 2))

    result = run("pso", 1, batch_objective(scalar), 600)
    assert len(scalar_calls) == result.evaluations == 600
    np.testing.assert_allclose(batch_objective(scalar)(np.array([CENTRE, CENTRE + 1])), [0.0, 14.0])


@pytest.mark.parametrize("bounds", [[(1.0, 1.0)], [(0.0, np.inf)], [], [(2.0, 1.0), (0.0, 1.0)]])
def test_bad_bounds_are_refused(bounds) -> None:
    with pytest.raises(ValueError, match="bounds"):
        METHODS["alo"](bowl, bounds, rng=np.random.default_rng(0), budget=500)


def test_objective_returning_wrong_length_is_refused() -> None:
    with pytest.raises(ValueError, match="costs"):
        METHODS["pso"](lambda p: np.zeros(1), BOUNDS, rng=np.random.default_rng(0), budget=100)


def test_shrink_ratio_follows_the_alo_schedule() -> None:
    # ALO paper: I = 1 up to 10 % of t_max, then 1 + 10^w t / t_max with w = 2, 3, 4, 5, 6.
    assert shrink_ratio(10, 100) == 1.0
    assert shrink_ratio(11, 100) == pytest.approx(1 + 100 * 0.11)
    assert shrink_ratio(51, 100) == pytest.approx(1 + 1e3 * 0.51)
    assert shrink_ratio(96, 100) == pytest.approx(1 + 1e6 * 0.96)
    ratios = [shrink_ratio(t, 300) for t in range(1, 301)]
    assert all(b >= a for a, b in zip(ratios[:-1], ratios[1:], strict=True))


def test_random_walks_stay_in_the_shrunk_trap_around_their_centre() -> None:
    rng = np.random.default_rng(0)
    low, high = np.full(4, -10.0), np.full(4, 10.0)
    centres = rng.uniform(-5, 5, (200, 4))
    for t in (1, 50, 95):
        ratio = shrink_ratio(t, 100)
        walks = random_walks(centres, low, high, t, 100, rng)
        assert np.all(np.abs(walks - centres) <= 10.0 / ratio + 1e-9)


def test_tent_logistic_cotangent_is_flat_on_the_unit_interval() -> None:
    x = np.random.default_rng(2).random(2000)
    iterates = []
    for _ in range(100):
        x = tent_logistic_cotangent(x)
        iterates.append(x)
    values = np.concatenate(iterates)
    assert np.all((values >= 0) & (values < 1))
    counts, _ = np.histogram(values, bins=20, range=(0, 1))
    # 200 000 iterates, 10 000 per bin: a flat histogram varies by about 1 %; 5 % flags a bad map.
    assert counts.std() / counts.mean() < 0.05


def test_chaotic_population_lies_within_bounds() -> None:
    low, high = np.array([0.0, -3.0]), np.array([1.0, 7.0])
    points = chaotic_population(500, low, high, np.random.default_rng(4))
    assert np.all(points >= low) and np.all(points < high)
    assert np.all(np.ptp(points, axis=0) > 0.9 * (high - low))  # it covers each range


def test_cosine_factors_end_in_a_pull_towards_the_origin() -> None:
    # Seed 002 eqs. 11-13 at t = t_max: cos h = 0, theta = w_min = 0.1, phi = 0.
    r_a, r_e = np.full((3, 2), 4.0), np.full((3, 2), 8.0)
    np.testing.assert_allclose(cosine_update(r_a, r_e, 100, 100, np.random.default_rng(0)), 0.04)
    start = cosine_update(r_a, r_e, 0, 100, np.random.default_rng(0))  # theta = 0.5, phi in [0.5, 1.5]
    assert np.all(start >= 0.25 * 4 + 0.25 * 8) and np.all(start <= 0.25 * 4 + 2.25 * 8)


def test_ocalo_options_are_checked() -> None:
    with pytest.raises(ValueError, match="map_r"):
        METHODS["ocalo"](bowl, BOUNDS, rng=np.random.default_rng(0), budget=500, map_r=1.5)
    with pytest.raises(ValueError, match="eobl_k"):
        METHODS["ocalo"](bowl, BOUNDS, rng=np.random.default_rng(0), budget=500, eobl_k=2.0)
    fixed = METHODS["ocalo"](bowl, BOUNDS, rng=np.random.default_rng(0), budget=500, eobl_k=1.0)
    assert fixed.evaluations == 500


@pytest.mark.parametrize("method", sorted(METHODS))
def test_an_objective_that_is_inf_everywhere_still_returns_an_evaluated_point(method: str) -> None:
    result = run(method, 0, lambda points: np.full(points.shape[0], np.inf), 500)
    assert result.cost == np.inf
    assert np.all(np.isfinite(result.x)) and np.all(np.abs(result.x) <= 5.0)


@pytest.mark.parametrize(("t", "t_max"), [(1, 1), (5, 13), (13, 13), (16, 16), (8, 300), (299, 300)])
def test_walk_summary_equals_the_walk_step_by_step(t: int, t_max: int) -> None:
    width = 50
    here, low, high = walk_summary(t, t_max, width, np.random.default_rng(9))
    blocks = -(-t_max // 8)
    codes = np.frombuffer(np.random.default_rng(9).bytes(blocks * width), dtype=np.uint8).reshape(blocks, width)
    steps = 2 * np.unpackbits(codes, axis=0)[:t_max].astype(int) - 1  # each byte's bits in time order
    walks = np.vstack([np.zeros(width, dtype=int), np.cumsum(steps, axis=0)])  # eq. 1: starts at 0
    np.testing.assert_array_equal(here, walks[t])
    np.testing.assert_array_equal(low, walks.min(axis=0))
    np.testing.assert_array_equal(high, walks.max(axis=0))


def test_de_puts_known_points_in_its_first_population():
    """A warm start: the rules' answers join DE's first population (clipped into the bounds), up to a
    third of it; the rest stays Latin-hypercube."""
    seen = []

    def objective(x: np.ndarray) -> np.ndarray:
        seen.append(np.array(x))
        return np.sum((x - 0.123) ** 2, axis=1)

    result = METHODS["de"](objective, [(0.0, 1.0)] * 3, rng=np.random.default_rng(0), budget=90,
                           starts=np.array([[0.123] * 3, [5.0, -1.0, 0.5]]))
    first = seen[0]
    assert first.shape == (45, 3)
    np.testing.assert_array_equal(first[:2], [[0.123] * 3, [1.0, 0.0, 0.5]])
    assert result.cost == 0.0 and "de" in WARM_STARTS


def test_de_shrinks_its_default_population_to_two_generations_of_a_small_budget():
    """Four parameters (scipy's population 60) on a budget of 90: a population of 45, two generations
    spent exactly; an explicit population is kept, and refused where the budget cannot pay for two."""
    calls: list[int] = []

    def bowl(x: np.ndarray) -> np.ndarray:
        calls.append(len(x))
        return np.sum(np.asarray(x) ** 2, axis=1)

    result = METHODS["de"](bowl, [[-1.0, 1.0]] * 4, rng=np.random.default_rng(0), budget=90)
    assert calls == [45, 45] and result.evaluations == 90
    with pytest.raises(ValueError, match="below two generations"):
        METHODS["de"](bowl, [[-1.0, 1.0]] * 4, rng=np.random.default_rng(0), budget=90, population=60)
    with pytest.raises(ValueError, match=r"budget 9 is below two generations of DE's smallest population \(10 "):
        METHODS["de"](bowl, [[-1.0, 1.0]] * 4, rng=np.random.default_rng(0), budget=9)
