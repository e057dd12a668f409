"""Seed 000's controllers and its printed results, reproduced (tools.seeds.seed000, firmware_port.seed000)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_port.seed000 import (
    AdaptivePidLaw,
    AnfisLaw,
    MlpWeights,
    SeedController,
    fuzzy_law,
    gaussian_law,
    gaussian_scheduler,
    triangular_scheduler,
)
from tools.seeds import seed000 as s0
from twin.engine import Twin

CONTROLLER_SAMPLE_S = 0.16384


def _random_network(seed: int) -> MlpWeights:
    rng = np.random.default_rng(seed)
    sizes = (2, 8, 8, 3)
    return MlpWeights(tuple((rng.normal(0, 1, (a, b)), rng.normal(0, 1, b)) for a, b in zip(sizes[:-1], sizes[1:], strict=True)))


# -- the fuzzy engine -------------------------------------------------------------------------------

def test_single_rule_gives_the_centroid_of_its_clipped_sets():
    # e = 10, de = 5: only rule 3 (positive, positive) fires, fully: Kp low, Ki low, Kd medium.
    # Exact centroids of triangles (0,0,5), (0,0,.5), (0,.5,1): 5/3, 1/6, 1/2; the sets are sampled on
    # 100 points, so the foot at 5 (between samples 4.949 and 5.051) moves the centroid by < 0.01.
    kp, ki, kd = triangular_scheduler().gains(10.0, 5.0)
    assert kp == pytest.approx(5 / 3, abs=0.01)
    assert ki == pytest.approx(1 / 6, abs=0.001)
    assert kd == pytest.approx(0.5, abs=1e-9)  # symmetric set: the centroid is exact


def test_sampled_sets_overlap_at_zero_change_of_error():
    # The [-5, 5] grid of 100 points has no sample at 0: "negative" interpolates to 0.0101 there,
    # which is why the seed's rule base never goes silent (a (positive, zero) input still fires rule 5).
    delta = triangular_scheduler().delta
    assert delta.degree("negative", 0.0) == pytest.approx(0.0101, abs=1e-4)
    assert delta.degree("positive", 0.0) == pytest.approx(0.0101, abs=1e-4)


@settings(max_examples=60, deadline=None)
@given(st.floats(-10, 10), st.floats(-5, 5), st.booleans())
def test_scheduled_gains_stay_in_their_universes(error, delta, gauss):
    sched = gaussian_scheduler() if gauss else triangular_scheduler()
    kp, ki, kd = sched.gains(error, delta)
    assert 0.0 <= kp <= 10.0 and 0.0 <= ki <= 1.0 and 0.0 <= kd <= 1.0


# -- the laws' own clamps and the board adaptor --------------------------------------------------

errors = st.lists(st.floats(-400, 400), min_size=1, max_size=40)


@settings(max_examples=40, deadline=None)
@given(errors)
def test_gaussian_law_holds_its_integral_and_output_clamps(seq):
    law = gaussian_law()
    for e in seq:
        u = law.step(e, 50.0)
        assert -100.0 <= u <= 100.0 and -50.0 <= law.integral <= 50.0


@settings(max_examples=40, deadline=None)
@given(errors, st.floats(1.0, 300.0))
def test_adaptive_law_output_within_zero_and_one_and_a_half_setpoints(seq, setpoint):
    law = AdaptivePidLaw(dt_s=CONTROLLER_SAMPLE_S)
    for e in seq:
        assert 0.0 <= law.step(e, setpoint) <= 1.5 * setpoint


@settings(max_examples=40, deadline=None)
@given(errors, st.integers(0, 20))
def test_anfis_law_holds_its_clamps_for_any_network(seq, seed):
    law = AnfisLaw(_random_network(seed), integral_gain=0.5, integral_limit=30.0)
    for e in seq:
        u = law.step(e, 50.0)
        assert -100.0 <= u <= 100.0 and -30.0 <= law.integral <= 30.0


def _controllers(seed: int):
    return {
        "fuzzy": SeedController(fuzzy_law()),
        "gauss": SeedController(gaussian_law()),
        "adaptive": SeedController(AdaptivePidLaw(dt_s=CONTROLLER_SAMPLE_S)),
        "anfis": SeedController(AnfisLaw(_random_network(seed))),
    }


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(-32768, 32767), st.integers(0, 400)), min_size=1, max_size=30),
       st.integers(0, 20))
def test_board_outputs_are_counts_0_to_255(readings, seed):
    for controller in _controllers(seed).values():
        controller.reset()
        for k, (temp_q5, target_c) in enumerate(readings):
            out = controller.update(temp_q5, target_c, 164 * k)
            assert isinstance(out, int) and 0 <= out <= 255
            if target_c == 0:
                assert out == 0


# -- the seed's loop vs a correct one --------------------------------------------------------------

@settings(max_examples=40, deadline=None)
@given(st.floats(0.05, 10), st.floats(0.001, 1), st.floats(0.001, 1), st.floats(0.001, 2))
def test_seed_loop_is_cg_over_c_plus_g_and_the_correct_one_cg_over_1_plus_cg(kp, ki, kd, w):
    s = 1j * w
    c = (kd * s * s + kp * s + ki) / s
    num, den = s0.plant_polynomials()
    g = np.polyval(num, s) / np.polyval(den, s)
    seed = s0.seed_closed_loop(kp, ki, kd, normalise=False)
    correct = s0.correct_closed_loop(kp, ki, kd)
    seed_h = np.polyval(seed.num, s) / np.polyval(seed.den, s)
    correct_h = np.polyval(correct.num, s) / np.polyval(correct.den, s)
    assert seed_h == pytest.approx(c * g / (c + g), rel=1e-9)
    assert correct_h == pytest.approx(c * g / (1 + c * g), rel=1e-9)


def test_seed_loop_heads_to_k_times_the_setpoint():
    # DC gain of CG/(C+G) with integral action is G(0) = K (5); normalised, the plant gain is 100.
    assert s0.loop_evidence(1.0, 0.1, 0.01, normalise=False)["seed_dc_gain"] == pytest.approx(5.0)
    assert s0.loop_evidence(1.0, 0.1, 0.01, normalise=True)["seed_dc_gain"] == pytest.approx(100.0)
    correct = s0.correct_closed_loop(1.0, 0.1, 0.01)
    assert correct.num[-1] / correct.den[-1] == pytest.approx(1.0)


def test_seed_metrics_definitions():
    t = np.linspace(0, 10, 11)
    y = np.array([0, 10, 30, 50, 60, 48, 50, 44, 50, 50, 50], dtype=float)
    m = s0.seed_metrics(t, y, 50.0)
    assert m["overshoot_pct"] == pytest.approx(20.0)
    assert m["settling_time_s"] == 7.0  # the last sample outside +-2.5
    assert m["rise_time_s"] == 6.0  # samples 1, 2 and 7 inside 10-90 %: t 1 to 7
    below = s0.seed_metrics(t, np.linspace(0, 49, 11), 50.0)
    assert below["overshoot_pct"] == 0.0 and below["settling_time_s"] == 10.0  # no overshoot: t_end


# -- the printed results -------------------------------------------------------------------------

@pytest.mark.parametrize("reproduce", [lambda: s0.reproduce_fuzzy("fuzzy"), lambda: s0.reproduce_fuzzy("gauss"),
                                       s0.reproduce_adaptive, s0.reproduce_nelder_mead],
                         ids=["fuzzy", "gauss", "adaptive", "nelder_mead"])
def test_deterministic_listings_reproduce_the_printed_metrics(reproduce):
    r = reproduce()
    assert r.reproduced, (r.printed, r.ours)
    for metric, printed in r.printed.items():
        assert r.ours[metric] == pytest.approx(printed, abs=r.tolerance[metric])


def test_nelder_mead_result_is_the_seed_loop_crossing_not_a_settled_loop():
    r = s0.reproduce_nelder_mead()
    assert r.gains is not None and r.gains[1] == pytest.approx(0.001)  # Ki pinned at its lower bound
    assert r.evidence["seed_final_value_c"] == pytest.approx(100 * s0.SETPOINT_C)


@pytest.mark.slow


def test_de_reproduces_the_printed_metrics_with_a_small_budget():
    # The printed run (popsize 50, 1000 generations) takes minutes; the optimum it finds is where the
    # seed's rising response crosses 50 exactly at t = 50 s, which a small seeded run also finds.
    r = s0.reproduce_de(np.random.default_rng(0), popsize=10, maxiter=60)
    assert r.reproduced, (r.printed, r.ours)
    assert r.evidence["seed_final_value_c"] == pytest.approx(s0.PLANT_GAIN_C_W * s0.SETPOINT_C)
    assert r.evidence["seed_slope_at_end_c_s"] > 0.1  # still rising at the "steady state"
    assert r.evidence["correct_max_pole_real"] < 0  # the same gains are stable in a correct loop


@pytest.mark.slow


def test_pso_seeded_run_lands_within_a_redraw_of_the_printed_one():
    r = s0.reproduce_pso(np.random.default_rng(0))
    assert r.reproduced, (r.printed, r.ours)


def test_refined_anfis_cannot_hold_the_setpoint_after_its_printed_settling_time():
    # Its loop multiplies u by the elapsed time: near the setpoint, with the gains its network is
    # trained to give, the one-step map is stable at first and unstable from ~1.2 s on.
    assert s0.anfis_label_radius("refined", 0.5) < 1.0
    assert s0.anfis_label_radius("refined", 2.71) > 3.0
    assert s0.anfis_label_radius("first", 2.71) <= 1.0 + 1e-12


def test_anfis_training_is_seeded_and_fits_the_labels():
    a = s0.train_anfis("first", np.random.default_rng(3))
    b = s0.train_anfis("first", np.random.default_rng(3))
    inputs, labels = s0.anfis_training_data("first")
    pred_a = np.array([a(e, de) for e, de in inputs[:200]])
    pred_b = np.array([b(e, de) for e, de in inputs[:200]])
    assert np.allclose(pred_a, pred_b, atol=1e-9)  # same seed, same network (up to BLAS rounding)
    # Kp spans 1..3 over the data: an RMS error under 0.05 is a fit, not a constant.
    assert np.sqrt(np.mean((pred_a[:, 0] - labels[:200, 0]) ** 2)) < 0.05


# -- on the firmware twin ----------------------------------------------------------------------

def test_registered_firmware_equals_the_injected_controller():
    by_name = Twin.create("seed000_gauss", hotend=s0.TWIN_PRESET)
    injected = Twin.create("pid", hotend=s0.TWIN_PRESET, controllers=[lambda: SeedController(gaussian_law())])
    for twin in (by_name, injected):
        twin.hotend.target_c = 75
    a, b = by_name.run(60.0).hotend, injected.run(60.0).hotend
    assert np.array_equal(a.measured_c, b.measured_c) and np.array_equal(a.duty, b.duty)


def test_gaussian_scheduler_on_a_saturating_heater_overshoots_more_than_in_the_seed_loop():
    # The seed's loop lets the signal cool (-100) and has no lag; the twin's heater only heats, up to
    # 40 W, into a second-order plant: the same law overshoots far beyond its printed 6.38 %.
    m = s0.twin_step(lambda: SeedController(gaussian_law()), duration_s=120.0)
    assert m.reached and m.overshoot_pct is not None and m.overshoot_pct > 2 * 6.38


@pytest.mark.slow


def test_takagi_sugeno_anfis_fits_the_labels():
    ts = s0.train_takagi_sugeno("first")
    inputs, labels = s0.anfis_training_data("first")
    rms = np.sqrt(np.mean((np.array([ts(e, de) for e, de in inputs]) - labels) ** 2, axis=0))
    # Kp and Kd labels are planes in (e, de): every rule can carry the same plane and the normalised
    # strengths sum to 1, so they are exact up to rounding. Ki = 0.01 |e| has a kink: fitted, not exact.
    assert rms[0] < 1e-6 and rms[2] < 1e-6
    assert rms[1] < 0.005
