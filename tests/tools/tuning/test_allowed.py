"""The plants a log allows: Akaike's evidence with scaled and with correlated residuals, profiles to the ends
of what a fit leaves open, the replay against the log's own numbers; on the Artillery bed's result lines the
data cannot choose between a first-order fit and a three-node one (both members, the three-node one as the
profiles that identify its lags: a degenerate fit is never a member), and an assumed cartridge capacity the
hotend capture excludes is dropped with its reason; a log that allows no plant says why of every structure."""

import numpy as np
import pytest

from tools.ident.result import FitResult
from tools.logs import load_log
from tools.tuning.allowed import EVIDENCE_MARGIN, Allowed, AllowedPlant, allowed_plants, evidence, halfway, profile_points


def fit(residuals: np.ndarray, n_params: int, evidence_kind: str = "trace") -> FitResult:
    params = {f"p{k}": 1.0 for k in range(n_params)}
    return FitResult("fopdt", params, {k: 0.1 for k in params}, {}, np.asarray(residuals, float),
                     evidence=evidence_kind)


def test_scaled_residuals_compare_by_chi_square_plus_twice_the_parameters():
    """Relay results are in units of their scatter: the criterion is sum(r^2) + 2 k."""
    best = fit(np.full(10, 0.6), 3, "relay results")
    more = fit(np.full(10, 0.5), 5, "relay results")  # 1.1 less chi-square for 2 more parameters
    assert evidence([best, more], [0, 0]) == pytest.approx([0.0, 4.0 - 1.1])
    assert evidence([best, more], [0, 1])[1] == pytest.approx(4.0 - 1.1 + 2.0)  # a held parameter is charged


def test_correlated_residuals_count_as_fewer_samples():
    """A trace's residuals that wander slowly carry fewer independent samples: the same 10 % less squared
    error buys far less evidence than it would from white residuals."""
    rng = np.random.default_rng(1)
    white = rng.normal(size=2000)
    walk = np.convolve(rng.normal(size=2100), np.ones(100) / 10.0, "valid")[:2000]  # lag-1 correlation ~0.99
    for residuals, expected in ((white, 2000 * np.log(0.9)), (walk, None)):
        delta = evidence([fit(residuals, 3), fit(residuals * np.sqrt(0.9), 3)], [0, 0])
        assert delta[1] == 0.0
        if expected is not None:
            assert delta[0] == pytest.approx(-expected, rel=0.01)  # white: n_eff is n, give or take its sample rho
        else:
            assert 0.0 < delta[0] < EVIDENCE_MARGIN  # white residuals would exclude it by about 210


def test_profiles_go_to_both_ends_of_what_the_fit_leaves_open_and_halfway():
    result = FitResult("fopdt", {"gain_c": 400.0, "time_constant_s": 1400.0, "delay_s": 8.0},
                       {"gain_c": 1.0, "time_constant_s": 2000.0, "delay_s": 0.1}, {"ambient_c": 25.0},
                       np.zeros(5), evidence="relay results", heater="heater_bed", assumed=("ambient_c",))
    points = profile_points(result)
    names = {name for name, _, _ in points}
    assert names == {"time_constant_s", "ambient_c"}  # the identified ones stay
    assert ("ambient_c", 25.0, 15.0) in points and ("ambient_c", 25.0, 35.0) in points
    assert halfway("time_constant_s", 100.0, 400.0) == pytest.approx(200.0)  # a logarithm: geometric
    assert halfway("ambient_c", 25.0, 35.0) == 30.0 and halfway("delay_s", 2.0, 0.0) == 1.0


@pytest.mark.slow
def test_the_bed_capture_allows_several_structures_and_each_replays_it(hardware_logs):
    log = load_log(hardware_logs / "m303_bed_artillery_genius_pro_S60_configs641.txt")
    allowed = allowed_plants(log, "bed")
    structures = {p.label.split(":")[0].split(",")[0] for p in allowed.members}
    assert {"fopdt", "three_node"} <= structures  # the result lines cannot choose between them
    assert allowed.heater == "heater_bed" and len(allowed.members) >= 4
    for plant in allowed.members:
        assert plant.delta <= EVIDENCE_MARGIN and plant.replay is not None and plant.replay.passed
        assert plant.replay.rows[0][0] == "Tu s"  # the twin's own M303 against the printed cycles
    reasons = {p.label: p.dropped for p in allowed.dropped}
    assert reasons["two_node"].startswith("the evidence excludes it")  # 4x the scatter: no
    # three_node fits as well but identifies none of its lags: no member; its profiles, which hold one, may be
    assert reasons["three_node"].startswith("degenerate: the data identify none of three_node's lags")
    assert all(p.fitted.degenerate is None for p in allowed.members)
    assert all(reasons.values())
    again = allowed_plants(log, "bed")  # the same log, the same plants
    assert [p.label for p in again.members] == [p.label for p in allowed.members]


@pytest.mark.slow
def test_a_cartridge_capacity_the_hotend_capture_excludes_is_dropped(hardware_logs):
    """At 8 J/K a three-node hotend's relay period is far off the capture's; the profile
    there is dropped (by the evidence, or by the twin's M303 missing the printed Tu), never a member."""
    log = load_log(hardware_logs / "m303_hotend_artillery_genius_pro_S210_configs641_partial.txt")
    allowed = allowed_plants(log, "hotend")
    at_8 = [p for p in allowed.dropped + allowed.members if "cartridge_heat_capacity_j_k 8 " in p.label]
    assert at_8 and all(p.dropped for p in at_8), [(p.label, p.dropped) for p in at_8]


def test_a_log_that_allows_no_plant_names_every_structure_tried_and_why():
    def dropped(label: str, why: str, held: int = 0) -> AllowedPlant:
        return AllowedPlant(label, None, 0.0, dropped=why, held=held)  # type: ignore[arg-type]  # reads no fit

    allowed = Allowed("bed.txt", "heater_bed", None, [], [  # type: ignore[arg-type]
        dropped("fopdt", "the evidence excludes it (delta 17.4 > 6)"),
        dropped("three_node", "degenerate: the data identify none of three_node's lags (...)"),
        dropped("three_node: ambient_c 35 (end high, fitted 25)", "does not replay the log: ...", held=1),
        dropped("sopdt", "does not replay the log: Tu s 21.97 / 14.07")])
    assert allowed.why_none() == (
        "no plant both fits it and replays it: fopdt: the evidence excludes it (delta 17.4 > 6); three_node: "
        "degenerate: the data identify none of three_node's lags (...); sopdt: does not replay the log: Tu s 21.97 / "
        "14.07; and none of their 1 profiles is a member")
