"""Plant ensembles and the proof: a preset's stated spread, the corner plants, the robust statistics,
member-major lanes equal to single-member runs on each seed, and a proof on the batch that counts the
very trips of scalar twins and whose cross-check on the reference engine catches a difference."""

from dataclasses import replace

import numpy as np
import pytest

from tools.tuning.ensemble import DEFAULT_SPREAD, NOMINAL, Ensemble, Member, Uncertain, corner_ensemble, preset_spread
from tools.tuning.evaluate import Evaluator, TuneScenario, preset_problem, run_scalars, simulate
from tools.tuning.objectives import heater_cost
from tools.tuning import proof
from tools.tuning.proof import cross_check, prove
from tools.tuning.tuner import runs
from twin.plants import SPECS

CARTRIDGE = preset_problem("hotend_cartridge", 210)
GAINS = np.array([[12.0, 0.37, 100.0], [30.0, 2.0, 50.0]])


def test_a_preset_spreads_its_lag_and_loss_terms_by_the_stated_default():
    spec = SPECS["hotend_cartridge"]
    spread = {u.name: u for u in preset_spread(spec)}
    assert set(spread) == {"sensor_responsiveness_per_s", "ambient_xfer_w_k", "fan_ambient_xfer_w_k",
                           "cartridge_heat_capacity_j_k", "cartridge_xfer_w_k"}  # no radiation: area inert
    r = spread["sensor_responsiveness_per_s"]  # one of three lag terms: the group's 20 % shared root-sum-square
    term = DEFAULT_SPREAD / 3 ** 0.5
    assert (r.low, r.high) == pytest.approx((spec.sensor_responsiveness_per_s * (1 - term),
                                            spec.sensor_responsiveness_per_s * (1 + term)))
    a = spread["ambient_xfer_w_k"]  # one of two loss terms
    assert a.high == pytest.approx(spec.ambient_xfer_w_k * (1 + DEFAULT_SPREAD / 2 ** 0.5))
    assert "block_heat_capacity_j_k" not in spread and "power_w" not in spread


def test_corners_move_each_group_to_its_ends():
    spec = SPECS["hotend_cartridge"]
    ensemble = corner_ensemble(preset_spread(spec), noise_lsb=1.0)
    assert [m.label for m in ensemble.members] == ["nominal", "lag+ loss+", "lag+ loss-", "lag- loss+", "lag- loss-"]
    assert len({m.seed for m in ensemble.members}) == ensemble.size and {m.noise_lsb for m in ensemble.members} == {1.0}
    seeds = [seed for _, seed in ensemble.runs()]  # every member on its own seeds, none shared
    assert len(seeds) == ensemble.lanes == ensemble.size * ensemble.seeds and len(set(seeds)) == len(seeds)
    more_lag = ensemble.members[1].spec(spec)
    assert more_lag.sensor_responsiveness_per_s < spec.sensor_responsiveness_per_s  # less responsive: more lag
    assert more_lag.cartridge_heat_capacity_j_k > spec.cartridge_heat_capacity_j_k
    assert more_lag.cartridge_xfer_w_k < spec.cartridge_xfer_w_k
    assert more_lag.ambient_xfer_w_k > spec.ambient_xfer_w_k  # loss+
    assert ensemble.members[4].spec(spec).ambient_xfer_w_k < spec.ambient_xfer_w_k
    assert corner_ensemble(()).size == 1  # no spread: the nominal plant only


def test_statistics():
    costs = np.array([[1.0, 10.0], [3.0, 10.0], [5.0, 10.0]])
    members = tuple(Member(str(k), (), 0.0, k) for k in range(3))
    assert Ensemble(members, "worst").reduce(costs).tolist() == [5.0, 10.0]
    assert Ensemble(members, "mean").reduce(costs).tolist() == [3.0, 10.0]
    assert Ensemble(members, "mean_std").reduce(costs) == pytest.approx([3.0 + np.std([1, 3, 5]), 10.0])
    with pytest.raises(ValueError, match="unknown statistic"):
        Ensemble(members, "median")
    with pytest.raises(ValueError, match="not a plant parameter"):
        Uncertain("colour", 0, 1, "")


def test_member_lanes_are_the_members_own_runs():
    """simulate runs every member on each of its seeds, member-major; each run's lanes equal that member
    run alone on that seed."""
    ensemble = corner_ensemble(preset_spread(CARTRIDGE.spec), noise_lsb=1.0, seeds=2)
    problem = replace(CARTRIDGE, ensemble=ensemble)
    run = simulate(problem, GAINS)
    assert run.n == ensemble.lanes * len(GAINS)
    for k, member in enumerate(problem.runs()):
        alone = simulate(member, GAINS)
        np.testing.assert_array_equal(run.temp_c[:, 2 * k:2 * k + 2], alone.temp_c)
    assert [p.seed for p in problem.runs()] == [seed for _, seed in ensemble.runs()]
    costs = heater_cost(run).reshape(ensemble.lanes, -1)
    np.testing.assert_array_equal(Evaluator(problem, heater_cost)(GAINS), ensemble.reduce(costs))
    (first, _) = runs(problem, heater_cost, GAINS, ["a", "b"])
    assert first.member_costs.tolist() == costs[:, 0].tolist() and first.run.n == ensemble.lanes
    assert NOMINAL.size == 1 and CARTRIDGE.members() == [CARTRIDGE]


@pytest.mark.slow  # 4.9 s of CPU: the proof against scalar twins
def test_the_proof_on_the_batch_counts_the_trips_of_scalar_twins():
    """250 s of heat-up with 1 LSB of noise: zero gains stall short of the target (outside the PID's band
    the law is bang-bang) and trip Marlin's protection on most plants, M303-like gains on some; the proof
    (every member on seeds 1..2, candidates and seeds as lanes of one batch per member) counts the very
    trips of one scalar fast-engine twin per case."""
    short = replace(CARTRIDGE, scenario=TuneScenario(210.0, 250.0, 25.0, ()),
                    ensemble=corner_ensemble(preset_spread(CARTRIDGE.spec), noise_lsb=1.0))
    table = np.array([[0.0, 0.0, 0.0], [12.0, 0.37, 100.0], [14.51, 0.4861, 268.1]])  # the last: a robust tune's
    candidates = runs(short, heater_cost, table, ["zero", "m303", "tuned"])
    rows = prove(short, candidates, seeds=2)
    members = [m.label for m in short.ensemble.members]
    assert [(r.member, r.method) for r in rows] == [(m, c) for m in members for c in ("zero", "m303", "tuned")]
    assert {r.runs for r in rows} == {2}
    scalar = {(label, seed): run_scalars(replace(member, seed=seed), table).tripped
              for label, member in zip(members, short.members()) for seed in (1, 2)}
    for r, k in zip(rows, [0, 1, 2] * len(members)):
        assert r.trips == sum(int(scalar[(r.member, seed)][k]) for seed in (1, 2))
    trips = {c: sum(r.trips for r in rows if r.method == c) for c in ("zero", "m303", "tuned")}
    assert trips["zero"] >= 6 and trips["m303"] >= 1 and trips["tuned"] == 0


def test_the_cross_check_equals_the_reference_engine_and_catches_a_difference(monkeypatch):
    """The batch's readings equal the tick-by-tick reference engine's over the checked stretch; a reference
    run that read differently (here: shifted by one LSB of temperature) stops the proof."""
    candidate = runs(CARTRIDGE, heater_cost, GAINS[:1], ["a"])[0]
    assert "bit for bit" in cross_check(CARTRIDGE, candidate, 20.0)
    real = proof.run_chunk

    def skewed(problem, params, record=True, seeds=None):
        traces = real(problem, params, record, seeds)
        if problem.engine == "reference":
            traces.temp_c[5:] += 0.03125
        return traces

    monkeypatch.setattr(proof, "run_chunk", skewed)
    with pytest.raises(RuntimeError, match="cross-check"):
        cross_check(CARTRIDGE, candidate, 20.0)


def test_a_corner_every_candidate_trips_on_is_left_out_never_the_nominal():
    """tune() drops a corner member on which every rule and reference trips (a plant no gains hold: the edge
    of what a fit cannot pin down), keeps one where some candidate survives, and never drops the nominal."""
    from types import SimpleNamespace

    from tools.tuning.tuner import hopeless_members, without_members

    ensemble = corner_ensemble(preset_spread(CARTRIDGE.spec), noise_lsb=1.0, seeds=1)
    problem = replace(CARTRIDGE, ensemble=ensemble)
    scored = [SimpleNamespace(run=SimpleNamespace(tripped=np.array(t, bool)))
              for t in ([1, 1, 0, 0, 1], [1, 1, 1, 0, 0], [1, 1, 0, 0, 1])]
    assert hopeless_members(problem, scored) == [1]
    kept = without_members(ensemble, [1])
    assert [m.label for m in kept.members] == ["nominal", "lag+ loss-", "lag- loss+", "lag- loss-"]
    assert hopeless_members(CARTRIDGE, scored) == []  # no ensemble: nothing to leave out
