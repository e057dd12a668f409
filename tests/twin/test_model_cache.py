"""A plant's discretisation caches stay bounded however a long session cuts its runs, and the bound
changes no result (an evicted map is rebuilt by the same computation)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from twin.linear import MAX_CACHED_MODELS, MAX_CACHED_RUNS
from twin.plants import make_plant

N_RUNS = 3000
GROWTH_BOUND_BYTES = 2 * MAX_CACHED_MODELS * MAX_CACHED_RUNS * 45_000  # maps of runs <= 160 ticks, 16 samples


def _drive(plant, rng: np.random.Generator, forget: bool) -> list[float]:
    """Random conditions (fan, flow) and run shapes, as a serial session's host events make them."""
    readings = []
    for _ in range(N_RUNS):
        if rng.random() < 0.05:
            plant.set_inputs(fan=rng.integers(256) / 255, flow_mm_s=round(rng.uniform(0, 20), 2), ambient_c=25.0)
        n = int(rng.integers(1, 161))
        offsets = tuple(sorted(set(rng.integers(0, n, rng.integers(0, 17)).tolist())))
        u = (rng.random(n) < 0.5).astype(float)
        if forget:
            plant.model._runs.clear()
        readings += plant.outputs(u, offsets)[:, 0].tolist()
        plant.advance(u)
    return readings


@pytest.mark.slow  # 4.1 s of CPU: 3000 runs
def test_the_caches_stay_bounded_over_ever_new_conditions_and_run_shapes():
    plant = make_plant()
    tracemalloc.start()
    _drive(plant, np.random.default_rng(3), forget=False)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert len(plant._models) <= MAX_CACHED_MODELS
    assert all(len(model._runs) <= MAX_CACHED_RUNS for model in plant._models.values())
    assert peak < GROWTH_BOUND_BYTES


def test_eviction_changes_no_result():
    cached = _drive(make_plant(), np.random.default_rng(4), forget=False)
    rebuilt = _drive(make_plant(), np.random.default_rng(4), forget=True)
    assert cached == rebuilt  # bit for bit


def test_a_range_of_radiating_bins_wider_than_the_bin_cache_is_built_whole(monkeypatch):
    """Lanes on many radiating plants (an ensemble of fits) ask for more bins than the cache keeps: the range
    asked for is stacked whole, the cache trimmed only after, and a second ask rebuilds the same tables."""
    from twin import lane_tables
    from twin.plants import SPECS, Plant

    monkeypatch.setattr(lane_tables, "MAX_CACHED_BINS", 3)
    monkeypatch.setattr(lane_tables, "_BINS", type(lane_tables._BINS)())
    monkeypatch.setattr(lane_tables, "_CACHE", type(lane_tables._CACHE)())
    plant = Plant("r", SPECS["hotend"].__class__(**{**vars(SPECS["hotend"]), "emissivity": 1.0}), 25.0)
    first = lane_tables.bin_tables(plant, plant.d, ((0, ()),), 160, 40, 47)
    assert first.px.shape[0] == 8 and len(lane_tables._BINS) == 3
    lane_tables._CACHE.clear()
    again = lane_tables.bin_tables(plant, plant.d, ((0, ()),), 160, 40, 47)
    np.testing.assert_array_equal(again.px, first.px)


def test_the_table_cache_keeps_what_fits_its_byte_bound_least_recently_used_out_first(monkeypatch):
    """Tables are kept while their arrays fit MAX_CACHED_TABLE_BYTES (the newest always), the least recently
    used dropped first: a cached table is the same object, a dropped one is rebuilt equal."""
    from twin import lane_tables
    from twin.plants import SPECS, Plant

    monkeypatch.setattr(lane_tables, "_CACHE", type(lane_tables._CACHE)())
    plants = [Plant(str(k), SPECS["hotend"].__class__(**{**vars(SPECS["hotend"]), "block_heat_capacity_j_k": 16.0 + k}), 25.0)
              for k in range(3)]

    def tables(k: int):
        return lane_tables.linear_tables(plants[k].model, plants[k].d, ((0, ()),), 160)

    size = lane_tables._nbytes(tables(0))
    monkeypatch.setattr(lane_tables, "MAX_CACHED_TABLE_BYTES", 2 * size)
    first, second = tables(0), tables(1)
    assert tables(0) is first  # a hit: now the most recently used
    third = tables(2)  # over the bound: the least recently used (plant 1's) goes
    assert len(lane_tables._CACHE) == 2 and tables(0) is first and tables(2) is third
    rebuilt = tables(1)
    assert rebuilt is not second
    np.testing.assert_array_equal(rebuilt.px, second.px)
    monkeypatch.setattr(lane_tables, "MAX_CACHED_TABLE_BYTES", 0)
    assert tables(0) is not None and len(lane_tables._CACHE) == 1  # the newest is always kept
