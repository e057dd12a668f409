"""Every tune on the batch: the evaluation dispatch, and the heater objective streamed by the lanes.

``simulate(..., record=False)`` keeps no trace: the lanes accumulate the heater objective's inputs
(twin/streaming.py). Its terms must equal those computed from the recorded trace of the same
candidates. The reading and the error are multiples of 1/32 C and the target a whole degree, so the
sums of |error| are exact in either order; the duty steps are |a - b| / 127, summed in counts then
divided (streamed) or divided then summed (trace): equal within 1e-12 of a chatter near 0.01..1.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from distributed import Client, LocalCluster

from tools.tuning.evaluate import Evaluator, preset_problem, run_chunk, run_scalars, simulate
from tools.tuning.objectives import heater_cost, heater_terms, itae, needs_trace
from twin.plants import ONION_RADIATING_PARAMS

CHATTER_TOLERANCE = 1e-12  # see the module docstring
FIELDS = ("reach_s", "overshoot_c", "hold_error_c", "chatter", "tripped")


def _radiating(loop: str = "marlin"):
    problem = preset_problem("hotend_cartridge", 210, loop=loop)
    return dataclasses.replace(problem, spec=dataclasses.replace(problem.spec, **ONION_RADIATING_PARAMS))


PROBLEMS = {
    "marlin pid": lambda: preset_problem("hotend_cartridge", 210),
    "marlin fuzzy PI": lambda: preset_problem("hotend_cartridge", 210, controller=_space("fuzzy_pi")),
    "marlin dead time": lambda: preset_problem("seed003_third", 150),
    "marlin radiating": _radiating,
    "klipper": lambda: preset_problem("hotend_cartridge", 210, loop="klipper"),
    "klipper dead time": lambda: preset_problem("seed003_third", 150, loop="klipper"),
}


def _space(name: str):
    from firmware_port.firmwares import param_space

    return param_space(name)


def _candidates(problem, n: int = 6, seed: int = 3) -> np.ndarray:
    """Random candidates inside the controller's bounds (log-uniform where the space searches so)."""
    rng = np.random.default_rng(seed)
    space = problem.controller
    low, high = space.to_search(space.bounds[:, 0]), space.to_search(space.bounds[:, 1])
    if space.pid:  # gains a heater can hold, not the whole domain
        low, high = np.array([2.0, 0.05, 10.0]), np.array([40.0, 3.0, 300.0])
    return np.array([space.hold(row) for row in space.from_search(rng.uniform(low, high, (n, space.dims)))])


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.slow) if name == "marlin radiating" else name
                                  for name in PROBLEMS])
def test_streamed_terms_are_the_trace_terms(name):
    problem = PROBLEMS[name]()
    assert problem.batched
    params = _candidates(problem)
    traced, streamed = simulate(problem, params), simulate(problem, params, record=False)
    assert streamed.streamed is not None and streamed.t_s.size == 0
    a, b = heater_terms(traced), heater_terms(streamed)
    for field in FIELDS:
        np.testing.assert_allclose(getattr(b, field), getattr(a, field), rtol=0,
                                   atol=CHATTER_TOLERANCE if field == "chatter" else 0, err_msg=field)


def test_the_evaluator_streams_the_heater_objective_only():
    problem = PROBLEMS["marlin pid"]()
    params = _candidates(problem, 4)
    assert not needs_trace(heater_cost) and needs_trace(itae)
    np.testing.assert_allclose(Evaluator(problem, heater_cost)(params), heater_cost(simulate(problem, params)),
                               rtol=1e-12)
    np.testing.assert_array_equal(Evaluator(problem, itae)(params), itae(simulate(problem, params)))


def test_dask_chunks_stream_the_in_process_numbers():
    problem = PROBLEMS["klipper"]()
    params = _candidates(problem, 40)  # two chunks of evaluate.CHUNK_LANES
    with LocalCluster(n_workers=2, processes=False, dashboard_address=None) as cluster, Client(cluster) as client:
        remote = simulate(problem, params, client, record=False)
    local = simulate(problem, params, record=False)
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(heater_terms(remote), field), getattr(heater_terms(local), field))


@pytest.mark.parametrize("name", ["marlin noisy", "marlin fuzzy PI", "marlin dead time", "klipper"])
def test_the_batch_path_is_the_scalar_path(name):
    """Problem.batched chooses the lanes; one twin per candidate (run_scalars) gives the same readings
    and duty, a noisy sensor included (each candidate sees the problem seed's draw), on the common clock
    (run_scalars samples every run on its first run's clock, which a trip changes)."""
    problem = {**PROBLEMS, "marlin noisy": lambda: dataclasses.replace(PROBLEMS["marlin pid"](), noise_lsb=1.0,
                                                                       seed=4)}[name]()
    problem = dataclasses.replace(problem, scenario=dataclasses.replace(problem.scenario, duration_s=300.0))
    params = _candidates(problem, 3)
    batch, scalar = run_chunk(problem, params), run_scalars(problem, params)
    skip = int(problem.loop == "marlin")  # run_chunk leaves Marlin's first reading out
    rows = min(batch.t_s.size, scalar.t_s.size - skip)
    apart = np.abs(batch.t_s[:rows] - scalar.t_s[skip:rows + skip]) > 1e-9
    rows = int(np.argmax(apart)) if apart.any() else rows
    assert rows > 500  # over 80 s of readings in common
    np.testing.assert_array_equal(batch.temp_c[:rows], scalar.temp_c[skip:rows + skip])
    np.testing.assert_array_equal(batch.duty[:rows], scalar.duty[skip:rows + skip])
