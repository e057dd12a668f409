"""Seed 001's fuzzy-PID: the rule tables, contracts of the integer port, its float oracle, the twin."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.controller import is_tunable
from firmware_port.fixed import INT16_MAX, INT16_MIN
from firmware_port.fuzzy_pid import (
    GRID,
    GRID_MAX,
    INCREMENTAL,
    K_BITS,
    LABELS,
    LITERAL,
    OUT_FRAC_BITS,
    OUT_MAX_Q8,
    POS_ONE,
    RULES,
    SEED001,
    SPAN_BITS,
    FuzzyPid,
    FuzzyPidConfig,
    FuzzyPidFloat,
    centroid,
    infer,
    memberships,
    parse_rule_table,
    ram_report,
)
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX, PidGains
from firmware_port.thermistor import B3950_TABLE, TEMP_ONE
from twin import Twin

TABLE_MIN_Q5, TABLE_MAX_Q5 = min(B3950_TABLE.temp_q5), max(B3950_TABLE.temp_q5)  # about -27..938 C
Q12 = 1 << 12

configs = st.builds(
    lambda ke_q12, kec, reading, span_q4: FuzzyPidConfig(ke=ke_q12 / (1 << K_BITS), kec=kec, reading=reading,
                                                          span=span_q4 / (1 << SPAN_BITS)),
    st.integers(1, 100 << K_BITS),
    st.floats(0.01, 100.0),
    st.sampled_from((LITERAL, INCREMENTAL)),
    st.integers(0, 1 << SPAN_BITS),
)
gains = st.builds(PidGains, st.floats(0.0, KP_MAX), st.floats(0.0, KI_MAX), st.floats(0.0, KD_MAX))
any_temps_q5 = st.integers(INT16_MIN, INT16_MAX)
table_temps_q5 = st.integers(TABLE_MIN_Q5, TABLE_MAX_Q5)
targets_c = st.integers(0, 300)


def centroid_bound() -> float:
    """Largest |integer - float| centroid, in units of the [0, 3] universe.

    1. Positions round to 1/2 Q8 unit; degrees have slope 1, and min, max and clipping are
       1-Lipschitz, so every aggregated output degree differs by at most delta = 1/512.
    2. c_int - c_float = sum((y - c_float) d_mu) / den_int over the 49 grid points. Each input's
       two degrees sum to 1, so some rule fires at >= 1/2 and den_int >= the grid sum of the edge
       output set clipped at 1/2 (3.25, the smallest of any set); sum |y - c_float| <= 48*49/2.
    3. A grid unit is 1/16; the centroid is rounded to 1/2 Q12 unit.
    """
    delta = 0.5 / POS_ONE
    den_min = sum(min(0.5, 1 - y / GRID) for y in range(GRID))
    return delta * (GRID_MAX * (GRID_MAX + 1) / 2) / den_min / (2 * GRID) + 0.5 / Q12


def factor_bound(config: FuzzyPidConfig) -> float:
    """|integer - float| gain factor: the centroid bound, scaled by the reading (+ one rounding)."""
    if config.reading == LITERAL:
        return centroid_bound()
    return config.span / 1.5 * centroid_bound() + 0.5 / Q12


# (a) the paper's tables --------------------------------------------------------------------------


def test_rule_tables_as_printed():
    """Fig. 7 corners and centre: rows e PB..NB, columns ec PB..NB as the paper prints them."""
    nb, zo, pb = LABELS.index("NB"), LABELS.index("ZO"), LABELS.index("PB")
    kp, ki, kd = RULES
    assert LABELS[kp[pb][pb]] == "NB" and LABELS[kp[nb][nb]] == "PB" and LABELS[kp[zo][zo]] == "ZO"
    assert LABELS[ki[pb][pb]] == "PB" and LABELS[ki[nb][nb]] == "NB"
    assert LABELS[kd[pb][nb]] == "PB" and LABELS[kd[nb][pb]] == "ZO" and LABELS[kd[nb][nb]] == "PS"
    with pytest.raises(ValueError, match="rule table"):
        parse_rule_table("NB NB\nNB NB")


@given(st.floats(-3.0, 3.0))
def test_memberships_partition_unity(x):
    assert sum(memberships(x)) == pytest.approx(1.0, abs=1e-12)


def test_centroid_of_one_full_set_is_its_centre():
    for j in range(7):
        strengths = [0.0] * 7
        strengths[j] = 1.0
        expected = j / 2 if 0 < j < 6 else None
        if expected is not None:
            assert centroid(strengths) == pytest.approx(expected, abs=1e-12)
    assert infer(0.0, 0.0) == pytest.approx((1.5, 1.5, 1.0), abs=1e-12)  # ZO, ZO, NS at the setpoint


# (b) range and overflow ---------------------------------------------------------------------------


@given(configs, gains, st.lists(st.tuples(any_temps_q5, targets_c), max_size=40))
def test_output_in_range_without_overflow(config, base, samples):
    """Any int16 reading, any target 0..300, any gains in PidGains' domain: no int32/int64 overflow
    (checked_s32/checked_s64 raise), output and integral stay in 0..255, target 0 gives 0."""
    ctl = FuzzyPid(base, config)
    for now_ms, (temp_q5, target_c) in enumerate(samples):
        out = ctl.update(temp_q5, target_c, now_ms * 164)
        assert 0 <= out <= 255
        assert 0 <= ctl.i_q8 <= OUT_MAX_Q8
        assert all(0 <= f <= 3 * Q12 for f in ctl.factors_q12)
        if target_c == 0:
            assert out == 0


# (c) integer port against the float oracle --------------------------------------------------------


@given(configs, st.integers(TABLE_MIN_Q5 - 300 * TEMP_ONE, TABLE_MAX_Q5), st.integers(-30000, 30000))
def test_factors_match_float(config, e_q5, derr_q5):
    """One inference: |factor_int - factor_float| <= factor_bound (derived in centroid_bound)."""
    ctl, ref = FuzzyPid(PidGains(1.0, 0.0, 0.0), config), FuzzyPidFloat.board(PidGains(1.0, 0.0, 0.0), config)
    got = ctl.infer_q12(e_q5, derr_q5)
    x_e = min(max(ref.ke * e_q5 / TEMP_ONE, -3.0), 3.0)
    x_ec = min(max(ref.kec * derr_q5 / TEMP_ONE / ref.dt_s, -3.0), 3.0)
    c_want = infer(x_e, x_ec)
    want = [c if config.reading == LITERAL else 1 + config.span * (c - 1.5) / 1.5 for c in c_want]
    for g, w in zip(got, want, strict=True):
        assert abs(g / Q12 - w) <= factor_bound(config) + 1e-12


@given(configs, gains, st.lists(st.tuples(table_temps_q5, targets_c), max_size=30))
def test_output_matches_float_over_sequences(config, base, samples):
    """Per step |P| and |D| differ by gain * |input| * factor_bound + one rounding; the integral's
    difference accumulates the same per step (its clamp does not expand it); outputs (Q8 vs float)
    differ by the sum, the truncated counts by at most floor(bound) + 1."""
    ctl, ref = FuzzyPid(base, config), FuzzyPidFloat.board(base, config)
    lsb, df = 0.5 / (1 << OUT_FRAC_BITS), factor_bound(config)
    di = 0.0
    for temp_q5, target_c in samples:
        e_prev, have_prev = ref.e_prev, ref.have_prev
        out_q8 = ctl.update_q8(temp_q5, target_c)
        out_f = ref.step(target_c - temp_q5 / TEMP_ONE) if target_c else (ref.reset() or 0.0)
        if target_c == 0:
            di = 0.0
            assert out_q8 == 0
            continue
        e = target_c - temp_q5 / TEMP_ONE
        derr = e - e_prev if have_prev else 0.0
        di += ref.ki * ref.dt_s * abs(e) * df + lsb
        bound = di + ref.kp * abs(e) * df + lsb + ref.kd / ref.dt_s * abs(derr) * df + lsb + 1e-6
        assert abs(ctl.i_q8 / (1 << OUT_FRAC_BITS) - ref.i_term) <= di + 1e-6
        assert abs(out_q8 / (1 << OUT_FRAC_BITS) - out_f) <= bound
        assert abs((out_q8 >> OUT_FRAC_BITS) - math.floor(out_f)) <= math.floor(bound) + 1


# (d) the law's shape ----------------------------------------------------------------------------


@given(configs, st.integers(1, 300 * TEMP_ONE))
def test_heats_below_and_cuts_above(config, e_q5):
    """Below the target the first output is positive: on a first sample ec is ZO, where every kp
    rule with e >= ZO gives ZO, NS or NM (centroid >= 0.5, factor > 0 in both readings).
    Above it, with a cold integral and no D, the output is zero."""
    base = PidGains(1.0, 0.1, 0.0)
    assert FuzzyPid(base, config).update_q8((200 << 5) - e_q5, 200) > 0
    hot = FuzzyPid(base, config)
    assert hot.update((200 << 5) + e_q5, 200) == 0


def test_incremental_zero_span_is_plain_pid():
    """span 0: every factor is exactly 1, so the law is the base PID (P + clamped I + D)."""
    ctl = FuzzyPid(PidGains(10.0, 0.5, 50.0), FuzzyPidConfig(ke=0.5, reading=INCREMENTAL, span=0.0))
    for temp_q5 in (0, 100 * TEMP_ONE, 190 * TEMP_ONE, 199 * TEMP_ONE):
        ctl.update(temp_q5, 200)
        assert ctl.factors_q12 == (Q12, Q12, Q12)


# (e) configuration, gains, size --------------------------------------------------------------


@pytest.mark.parametrize("field, value", [
    ("ke", 0.0), ("ke", -1.0), ("ke", math.nan), ("kec", math.inf), ("kec", 101.0),
    ("reading", "both"), ("span", 1.5), ("span", 0.3), ("span", -0.0625),
])
def test_config_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        FuzzyPidConfig(**{field: value})


def test_gains_are_tunable_and_reset_the_loop():
    """M301 sets the base gains; both versions expose them as the Tunable protocol wants."""
    for ctl in (FuzzyPid(), FuzzyPidFloat.board()):
        assert is_tunable(ctl)
        ctl.update(100 * TEMP_ONE, 200)
        ctl.set_gains(PidGains(5.0, 0.2, 30.0))
        assert ctl.gains == PidGains(5.0, 0.2, 30.0)
    assert FuzzyPid(PidGains(5.0, 0.2, 30.0)).k.kp_q12 == 5 * Q12


def test_ram_report():
    """7 bytes of state and 22 of gains and factors per heater; 147 bytes of rule tables in flash."""
    assert ram_report() == {"state_bytes": 7, "config_bytes": 22, "table_bytes": 147, "stack_bytes": 14}


def test_paper_config():
    assert (SEED001.ke, SEED001.kec, SEED001.reading) == (0.4, 0.6, LITERAL)


# (f) on the twin ------------------------------------------------------------------------------


def test_fuzzy_pid_firmware_heats_and_holds_the_hotend():
    """The registered build on Marlin's MPC hotend: reaches 200 C within 150 s, overshoots under
    10 C (Marlin's PID on the same plant: 0.5 C), holds within 0.5 C over the last 100 s."""
    twin = Twin.create("fuzzy_pid")
    twin.hotend.target_c = 200
    run = twin.run(400).hotend
    m = run.metrics()
    assert m.time_to_band_s is not None and m.time_to_band_s < 150
    assert m.overshoot_c is not None and m.overshoot_c < 10
    tail = run.measured_c[run.t_s > 300]
    assert max(abs(tail - 200)) <= 0.5
