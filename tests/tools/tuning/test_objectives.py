"""Objectives and metric variants: seed 000's metric code reproduced, the heater objective's
terms on responses built by hand, per-phase ITAE, seed 002's Q, lanes scored independently."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tools.tuning.objectives import (
    BAND_C,
    CHATTER_BOUND,
    CHATTER_S,
    HOLD_S_PER_C,
    OBJECTIVES,
    OVERSHOOT_BOUND_C,
    OVERSHOOT_S_PER_C,
    SEED002_W,
    TRIP_S,
    Run,
    heater_terms,
    itae,
    objective,
    seed000_metrics,
    seed002_metrics,
    seed002_q,
)

T = np.linspace(0.0, 50.0, 500)  # seed 000's time vector


def seed000_listing(time, response, setpoint):
    """Seed 000's calculate_metrics, as printed in its listings (the oracle)."""
    overshoot = max(response) - setpoint if max(response) > setpoint else 0
    steady_state_error = abs(response[-1] - setpoint)
    settling_time = time[np.where(abs(response - setpoint) > 0.05 * setpoint)[0][-1]] if max(response) > setpoint \
        else time[-1]
    rise_time_idx = np.where((response >= 0.1 * setpoint) & (response <= 0.9 * setpoint))[0]
    rise_time = time[rise_time_idx[-1]] - time[rise_time_idx[0]] if len(rise_time_idx) > 1 else None
    return overshoot, steady_state_error, settling_time, rise_time


def second_order(zeta: float, wn: float, setpoint: float) -> np.ndarray:
    wd = wn * np.sqrt(1 - zeta * zeta)
    return setpoint * (1 - np.exp(-zeta * wn * T) * (np.cos(wd * T) + zeta * wn / wd * np.sin(wd * T)))


@settings(max_examples=40, deadline=None)
@given(st.floats(0.1, 0.95), st.floats(0.1, 2.0), st.floats(10.0, 200.0))
def test_seed000_metrics_are_its_listing(zeta, wn, setpoint):
    y = second_order(zeta, wn, setpoint)
    overshoot, sse, settling, rise = seed000_listing(T, y, setpoint)
    m = seed000_metrics(T, y[:, None], setpoint)
    assert m.overshoot_c[0] == overshoot
    assert m.steady_state_error_c[0] == sse
    assert m.settling_time_s[0] == settling
    assert (np.isnan(m.rise_time_s[0]) if rise is None else m.rise_time_s[0] == rise)
    assert m.overshoot_pct[0] == pytest.approx(100 * overshoot / setpoint)


def test_seed000_settling_is_the_window_end_without_overshoot():
    """The seed's rule: no overshoot, no settling measured: the last sample's time."""
    y = 50 * (1 - np.exp(-T / 5))
    assert seed000_metrics(T, y[:, None], 50.0).settling_time_s[0] == T[-1]


def _run(temp, duty=None, *, target=210.0, start=25.0, disturbances=(), tripped=False, gains=(1.0, 0.1, 10.0),
         t=None) -> Run:
    temp = np.asarray(temp, float)
    t = np.arange(temp.shape[0]) * 0.5 if t is None else t
    duty = np.zeros_like(temp) if duty is None else duty
    return Run(t, temp, duty, target, start, tuple(disturbances), tripped, np.array(gains))


def ramp_hold(overshoot_c: float, reach_s: float = 100.0, end_s: float = 400.0, dt: float = 0.5) -> np.ndarray:
    """25 C -> 210 C linearly in reach_s, a triangular overshoot peak for 10 s, then 210 C."""
    t = np.arange(0.0, end_s, dt)
    temp = np.where(t < reach_s, 25 + 185 * t / reach_s, 210.0)
    peak = (t >= reach_s) & (t < reach_s + 10)
    temp[peak] += overshoot_c * (1 - np.abs(t[peak] - reach_s - 5) / 5)
    return temp


@pytest.mark.parametrize("overshoot_c", [0.0, 2.0, 7.5])
def test_heater_terms_on_a_hand_made_heatup(overshoot_c):
    run = _run(ramp_hold(overshoot_c), disturbances=(300.0,))
    terms = heater_terms(run)
    # the band edge 208 C is crossed at 100 s x 183/185; the first sample at or after it
    first_in_band_s = np.ceil(100.0 * (185 - BAND_C) / 185 / 0.5) * 0.5
    assert terms.reach_s[0] == pytest.approx(first_in_band_s)
    assert terms.overshoot_c[0] == pytest.approx(overshoot_c)
    expected = first_in_band_s + OVERSHOOT_S_PER_C * max(overshoot_c - OVERSHOOT_BOUND_C, 0.0) \
        + HOLD_S_PER_C * terms.hold_error_c[0]
    assert OBJECTIVES["heater"][0](run)[0] == pytest.approx(expected)


def test_heater_cost_penalises_trips_chatter_and_never_reaching():
    temp = ramp_hold(0.0)
    base = OBJECTIVES["heater"][0](_run(temp))[0]
    assert OBJECTIVES["heater"][0](_run(temp, tripped=True))[0] == pytest.approx(base + TRIP_S)
    duty = np.where(np.arange(temp.size) % 2, 0.5, 0.4)  # 0.1 of full power flipped every reading
    chatter = heater_terms(_run(temp, duty)).chatter[0]
    assert chatter == pytest.approx(0.1)
    assert OBJECTIVES["heater"][0](_run(temp, duty))[0] == pytest.approx(base + CHATTER_S * (0.1 - CHATTER_BOUND))
    cold = heater_terms(_run(np.full(temp.size, 100.0)))
    assert cold.reach_s[0] > temp.size * 0.5  # never reached: the heat-up's length plus the penalty


def test_itae_restarts_its_clock_at_each_disturbance():
    t = np.linspace(0.0, 300.0, 3001)
    run = _run(np.full(t.size, 209.0), t=t, disturbances=(100.0, 200.0))  # |e| = 1 throughout
    # three phases of 100 s, each integral of (t - t_phase) dt = 100^2 / 2
    assert itae(run)[0] == pytest.approx(3 * 100.0 ** 2 / 2, rel=1e-3)


def test_seed002_q_weights_overshoot_and_effort():
    t = np.linspace(0.0, 100.0, 1001)
    below = _run(np.full(t.size, 208.0), np.full(t.size, 0.5), t=t)
    above = _run(np.full(t.size, 212.0), np.full(t.size, 0.5), t=t)
    w1, w2, w3 = SEED002_W
    assert seed002_q(below)[0] == pytest.approx(100 * (w1 * 2 + w2 * 0.25))
    assert seed002_q(above)[0] == pytest.approx(100 * (w1 * 2 + w2 * 0.25 + w3 * 2))


def test_seed002_recovery_after_a_load():
    t = np.arange(0.0, 1000.0, 1.0)
    temp = np.where(t < 520, 210.0, 210.0 - 20 * np.exp(-(t - 520) / 50))
    m = seed002_metrics(_run(temp, t=t, disturbances=(520.0,)))
    assert m.max_deviation_c[0] == pytest.approx(20.0)
    band = 0.02 * 185  # 2 % of the step
    assert m.recovery_time_s[0] == pytest.approx(50 * np.log(20 / band), abs=1.0)  # sample times: 1 s


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(0.0, 30.0), min_size=2, max_size=5), st.integers(0, 2**32 - 1))
def test_every_objective_scores_each_lane_alone(overshoots, seed):
    """A batch's cost of lane i is the cost of lane i run on its own."""
    rng = np.random.default_rng(seed)
    temps = np.column_stack([ramp_hold(o) + rng.normal(0, 0.2, 800) for o in overshoots])
    duty = rng.uniform(0, 1, temps.shape)
    gains = rng.uniform(0, 100, (len(overshoots), 3))
    run = Run(np.arange(800) * 0.5, temps, duty, 210.0, 25.0, (300.0,), rng.random(len(overshoots)) < 0.3, gains)
    for name, (cost, _) in OBJECTIVES.items():
        together = cost(run)
        alone = np.concatenate([cost(run.lanes([i])) for i in range(run.n)])
        np.testing.assert_allclose(together, alone, rtol=1e-12, err_msg=name)


def test_an_unknown_objective_names_the_valid_ones():
    with pytest.raises(ValueError, match="choose one of: heater, itae"):
        objective("fastest")
