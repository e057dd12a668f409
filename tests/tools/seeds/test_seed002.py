"""Seed 002's PID experiment: the eq. 15 loop, the eq. 17 objective, and the reproduction."""

from __future__ import annotations

import numpy as np
import pytest

from tools.seeds import seed002

COARSE_S = 0.5  # a coarser step keeps the tests quick; the plant stays exact between samples (ZOH)


def test_no_gains_no_heat_and_q_is_the_whole_error() -> None:
    t, temp, out = seed002.simulate(np.zeros((1, 3)), sample_s=COARSE_S)
    assert np.all(temp == 0) and np.all(out == 0)
    # e = 210 C for 1000 s, u = 0: Q = w1 * 210 * 1000 exactly (rectangle rule, constant integrand).
    q = seed002.q_cost(np.zeros((1, 3)), sample_s=COARSE_S)[0]
    assert q == pytest.approx(seed002.W1 * seed002.SETPOINT_C * seed002.HORIZON_S, rel=1e-12)


def test_dead_time_and_proportional_offset() -> None:
    kp = 2e-4  # loop gain 1014 * 2e-4 = 0.2: stable, settles to 210 * 0.2 / 1.2 = 35 C
    t, temp, _ = seed002.simulate(np.array([[kp, 0.0, 0.0]]), sample_s=COARSE_S)
    assert np.all(temp[0, t <= seed002.DEAD_TIME_S] == 0)  # nothing before the dead time has passed
    assert temp[0, t > seed002.DEAD_TIME_S + 1][0] > 0
    loop = kp * seed002.PLANT_NUM / seed002.PLANT_DEN[2]
    assert temp[0, -1] == pytest.approx(seed002.SETPOINT_C * loop / (1 + loop), rel=1e-3)


def test_integral_action_removes_the_offset_and_overshoot_is_charged() -> None:
    calm, lively = np.array([1.3e-3, 2.2e-5, 0.028]), np.array([1.3e-3, 2e-4, 0.0])
    _, temp, _ = seed002.simulate(np.array([calm, lively]), sample_s=COARSE_S, horizon_s=2000)
    assert temp[0, -1] == pytest.approx(seed002.SETPOINT_C, abs=0.05)
    assert temp[1].max() > seed002.SETPOINT_C * 1.05  # too much integral overshoots
    costs = seed002.q_cost(np.array([calm, lively]), sample_s=COARSE_S)
    assert costs[1] > 2 * costs[0]  # w3 = 100 on the overshoot


def test_diverging_loops_cost_inf_or_more_than_any_stable_one() -> None:
    costs = seed002.q_cost(np.array([[1e5, 1e5, 1e5], [1.3e-3, 2.2e-5, 0.028]]), sample_s=COARSE_S)
    assert costs[0] == np.inf and np.isfinite(costs[1])


def test_evidence_against_printed_numbers() -> None:
    model = " ".join(seed002.model_consistency())
    assert "omega = sqrt(0.001) = 0.0316" in model and "zeta = 0.05/(2 omega) = 0.791" in model
    assert "k omega^2 = 0.9938, not 1.014" in model and "delay theta = 0 s" in model
    assert "WALO 218.2119 C below OCALO's 219.3011 C" in seed002.printed_claims()[0]


def test_printed_platform_gains_diverge_on_the_printed_model() -> None:
    for row in seed002.PRINTED_TABLE11.values():
        gains = tuple(g / seed002.COUNTS_PER_DUTY for g in row[3:])
        numbers = seed002.loop_numbers(gains, COARSE_S)
        assert numbers.overshoot_pct > 100 and numbers.settling_time_s is None


@pytest.mark.slow


def test_reproduce_is_deterministic_and_reports_both_optimisers() -> None:
    settings = {"seed": 1, "population": 8, "iterations": 6, "sample_s": COARSE_S, "reference_budget": 90}
    first, again = seed002.reproduce(**settings), seed002.reproduce(**settings)
    assert set(first.ours) == {"ALO", "OCALO"} == set(first.printed_gains_on_model)
    for name, numbers in first.ours.items():
        assert numbers.gains == again.ours[name].gains  # same seed, same run, one CPU: equal exactly
        assert first.runs[name].evaluations == 48
        assert numbers.q == pytest.approx(first.runs[name].cost, rel=1e-12)
        assert all(0 <= g <= 1e5 for g in numbers.gains)
    assert len(first.evidence) == 3
    assert first.reference.gains == again.reference.gains and first.reference_run.evaluations <= 90
    _, _, out = seed002.simulate(np.array([first.reference.gains]), sample_s=COARSE_S)
    assert first.reference.min_control == out.min()  # the lowest input the loop asked of the heater
