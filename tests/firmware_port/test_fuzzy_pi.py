"""The fuzzy-like PI of seed 004: contracts of the integer port, its float oracle, a closed loop."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.fixed import INT16_MAX, INT16_MIN
from firmware_port.fuzzy_pi import (
    BR_BITS,
    CENTROID_BITS,
    DU_FRAC_BITS,
    DUTY_BITS,
    GRID_BITS,
    MU_ONE,
    N_SETS_MAX,
    N_SETS_MIN,
    SEED004_BED,
    SEED004_BED_SETPOINT_C,
    SEED004_HOTEND,
    SEED004_HOTEND_SETPOINT_C,
    FuzzyPi,
    FuzzyPiConfig,
    FuzzyPiFloat,
    membership,
    membership_pct,
    ram_report,
)
from firmware_port.marlin.constants import PID_DT_S, SOFT_PWM_MAX
from firmware_port.thermistor import B3950_TABLE, TEMP_ONE, q5_to_c

TABLE_MIN_Q5, TABLE_MAX_Q5 = min(B3950_TABLE.temp_q5), max(B3950_TABLE.temp_q5)  # about -27..938 C
DUTY_ONE = 1 << DUTY_BITS
GRID = 1 << GRID_BITS

configs = st.builds(
    lambda n, err_q5, derr_q5, du_q4, out_max: FuzzyPiConfig(
        err_range_c=err_q5 / TEMP_ONE,
        derr_range_c=derr_q5 / TEMP_ONE,
        du_range_counts=du_q4 / (1 << DU_FRAC_BITS),
        n_sets=n,
        out_max=out_max,
    ),
    st.sampled_from(range(N_SETS_MIN, N_SETS_MAX + 1, 2)),
    st.integers(1, INT16_MAX),
    st.integers(1, INT16_MAX),
    st.integers(1, 255 << DU_FRAC_BITS),
    st.integers(0, 255),
)
any_temps_q5 = st.integers(INT16_MIN, INT16_MAX)
table_temps_q5 = st.integers(TABLE_MIN_Q5, TABLE_MAX_Q5)
targets_c = st.integers(0, 275)


def step_bound_counts(config: FuzzyPiConfig) -> float:
    """Largest |integer - float| change of duty in one step, in counts of 0..255.

    1. Eq. (1) on the integer axis rounds the position to 1/2 unit (br/4096); the memberships
       have slope 1 Q12 unit per unit, and min, max and clipping are 1-Lipschitz, so every
       aggregated output degree differs from the float one by at most delta = 1/8192.
    2. Sampled centroid c = sum(y*mu)/sum(mu): c_int - c_float = sum((y - c_float)*d_mu)/den_int.
       Some rule fires at >= 1/2 (each input's two degrees sum to 1), so den_int >= the grid sum
       of one output set clipped at 1/2 (6.0 for 8 points a set). Per input the two versions'
       sets with a non-zero degree are at most 3 neighbours, so the fired output sets are at most
       5 neighbours spanning 6*8 grid units, and sum|y - c_float| <= 48*49/2.
    3. The centroid is rounded to 1/1024 grid unit (Q9, half a unit) and the change to 2**-17
       count; a grid unit is du_range/(8n) counts. Plus 1e-9 for the float's own rounding.
    """
    delta = 0.5 / MU_ONE
    den_min = sum(min(0.5, 1 - abs(d) / GRID) for d in range(-GRID, GRID + 1))
    span = 6 * GRID
    centroid_grid = delta * span * (span + 1) / 2 / den_min + 0.5 / (1 << CENTROID_BITS)
    return centroid_grid * config.du_range_counts / (GRID * config.n_sets) + 0.5 / DUTY_ONE + 1e-9


# (a) range ------------------------------------------------------------------------------------


@given(configs, st.lists(st.tuples(any_temps_q5 | table_temps_q5, targets_c), max_size=60))
def test_output_within_0_out_max(config, samples):
    """Any temperatures the int16 reading can hold, any target: output and state stay in range."""
    ctl = FuzzyPi(config)
    for now_ms, (temp_q5, target_c) in enumerate(samples):
        out = ctl.update(temp_q5, target_c, now_ms * 164)
        assert 0 <= out <= config.out_max
        assert 0 <= ctl.duty_q16 <= config.out_max << DUTY_BITS
        if target_c == 0:
            assert out == 0


# (b) zero error and zero change of error -------------------------------------------------------


@given(configs, st.lists(table_temps_q5, max_size=20), st.integers(1, 275))
def test_duty_holds_at_setpoint(config, history_q5, target_c):
    """After any history, two successive samples at the target leave the duty unchanged."""
    ctl, ref = FuzzyPi(config), FuzzyPiFloat(config)
    for temp_q5 in [*history_q5, target_c * TEMP_ONE]:
        ctl.update(temp_q5, target_c, 0)
        ref.update(temp_q5, target_c, 0)
    duty_q16, duty = ctl.duty_q16, ref.duty
    ctl.update(target_c * TEMP_ONE, target_c, 0)
    ref.update(target_c * TEMP_ONE, target_c, 0)
    assert ctl.duty_q16 == duty_q16
    assert ref.duty == pytest.approx(duty, abs=1e-9)  # the float centroid of a lone set: 50 +- ulp


# (c) integer port against the float oracle -----------------------------------------------------


@given(configs, st.integers(-(1 << 17), 1 << 17), st.integers(-(1 << 18), 1 << 18))
def test_change_matches_float_per_step(config, err_q5, derr_q5):
    """One step of the law: |int - float| <= step_bound_counts (derived in its docstring).

    The integer products wrap at int32 (wrap_s32) as on the AVR; an overflow anywhere in the
    declared domain (n <= 31, ranges up to int16, du_range up to 255) would break this bound.
    """
    got = FuzzyPi(config).change_q16(err_q5, derr_q5) / DUTY_ONE
    want = FuzzyPiFloat(config).change(err_q5 / TEMP_ONE, derr_q5 / TEMP_ONE)
    assert abs(got - want) <= step_bound_counts(config)


@given(configs, st.lists(st.tuples(table_temps_q5, targets_c), max_size=30))
def test_duty_matches_float_over_sequences(config, samples):
    """Accumulated: after k steps since a reset, |duty_int - duty_float| <= k * step bound.

    Both see the same error exactly (celsius_q5 values are exact in float) and the clamp to
    [0, out_max] does not expand a difference; the returned counts (rounded halves up) then
    differ by at most floor(bound) + 1.
    """
    ctl, ref = FuzzyPi(config), FuzzyPiFloat(config)
    steps = 0
    for temp_q5, target_c in samples:
        out, ref_out = ctl.update(temp_q5, target_c, 0), ref.update(temp_q5, target_c, 0)
        steps = 0 if target_c == 0 else steps + 1
        bound = steps * step_bound_counts(config)
        assert abs(ctl.duty_q16 / DUTY_ONE - ref.duty) <= bound
        assert abs(out - ref_out) <= math.floor(bound) + 1


# (d) symmetry, sign and monotonicity -----------------------------------------------------------


@given(configs, st.integers(-(1 << 17), 1 << 17), st.integers(-(1 << 18), 1 << 18))
def test_law_is_odd_and_signed_by_quadrant(config, err_q5, derr_q5):
    """Contract: the integer law is exactly odd, and an error and change of error of one sign
    (or zero) give a change of that sign, in both versions.

    Odd: eq. (1) rounds halves away from zero, the sets and the Table 1 rules mirror about the
    zero sets, and the centroid sums about the support's midpoint with odd rounding. Sign: with
    e, ce >= 0 every fired output set is the zero set or right of it; the zero set is symmetric,
    so the aggregate right of its centre dominates the mirror of its left, and the centroid is
    at or right of the centre (also on the sampled grid).
    """
    ctl, ref = FuzzyPi(config), FuzzyPiFloat(config)
    change_q16 = ctl.change_q16(err_q5, derr_q5)
    assert ctl.change_q16(-err_q5, -derr_q5) == -change_q16
    if err_q5 >= 0 and derr_q5 >= 0:
        assert change_q16 >= 0
        assert ref.change(err_q5 / TEMP_ONE, derr_q5 / TEMP_ONE) >= -1e-9
    if err_q5 > 0 and derr_q5 == 0:
        assert ref.change(err_q5 / TEMP_ONE, 0.0) > 0


@given(configs, st.integers(-(1 << 16), 1 << 16), st.integers(-(1 << 16), 1 << 16), st.integers(0, 512))
def test_law_is_non_decreasing(config, err_q5, derr_q5, step_q5):
    """Checked, not proved: more error or more change of error never asks for less duty, up to
    one rounding step of the Q9 centroid (du_range_q4 / n Q16 units, rounded up)."""
    ctl = FuzzyPi(config)
    slack_q16 = -(-int(config.du_range_counts * (1 << DU_FRAC_BITS)) // config.n_sets) + 1
    base = ctl.change_q16(err_q5, derr_q5)
    assert ctl.change_q16(err_q5 + step_q5, derr_q5) >= base - slack_q16
    assert ctl.change_q16(err_q5, derr_q5 + step_q5) >= base - slack_q16


# (e) the sets partition unity ------------------------------------------------------------------


@given(st.sampled_from(range(N_SETS_MIN, N_SETS_MAX + 1, 2)), st.data())
def test_memberships_sum_to_one(n, data):
    """At every point of the axis the degrees of all sets sum to 1: exactly in Q12 on the input
    axis and in Q3 on the output grid (2n - 1 sets), to 1e-12 in the paper's float form."""
    pos = data.draw(st.integers(0, (n + 1) << BR_BITS))
    assert sum(membership(pos, k, n, MU_ONE) for k in range(n)) == MU_ONE
    y = data.draw(st.integers(0, 2 * n * GRID))
    assert sum(membership(y, k, 2 * n - 1, GRID) for k in range(2 * n - 1)) == GRID
    val = data.draw(st.floats(0.0, 100.0))
    assert sum(membership_pct(val, k, n) for k in range(n)) == pytest.approx(1.0, abs=1e-12)


# (f) configuration ----------------------------------------------------------------------------


GOOD = {"err_range_c": 300.0, "derr_range_c": 3.0, "du_range_counts": 64.0}


@pytest.mark.parametrize(
    "field, value",
    [
        ("n_sets", 8),
        ("n_sets", 1),
        ("n_sets", N_SETS_MAX + 2),
        ("n_sets", 9.0),
        ("err_range_c", 0.0),
        ("err_range_c", -10.0),
        ("err_range_c", 1 / 64),
        ("err_range_c", 1024.0),
        ("err_range_c", math.nan),
        ("derr_range_c", math.inf),
        ("derr_range_c", 0.01),
        ("du_range_counts", 0.0),
        ("du_range_counts", 1 / 32),
        ("du_range_counts", 256.0),
        ("du_range_counts", "64"),
        ("out_max", -1),
        ("out_max", 256),
        ("out_max", 220.5),
    ],
)
def test_config_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        FuzzyPiConfig(**{**GOOD, field: value})


def test_presets_follow_the_paper():
    """Section 4: n = 9 on both, out_max 255 and 220, error range = the input span."""
    assert (SEED004_HOTEND.n_sets, SEED004_HOTEND.out_max, SEED004_HOTEND.err_range_c) == (9, 255, 300.0)
    assert (SEED004_BED.n_sets, SEED004_BED.out_max, SEED004_BED.err_range_c) == (9, 220, 120.0)


def test_ram_report():
    """9 bytes of state and 8 of settings per heater, no tables (breakpoints are shifts)."""
    assert ram_report(SEED004_HOTEND) == {
        "state_bytes": 9,
        "config_bytes": 8,
        "table_bytes": 0,
        "float_abc_table_bytes": 420,
    }


# closed loop ----------------------------------------------------------------------------------


def run_first_order(config, setpoint_c, capacity_j_k, power_w, loss_w_k, duration_s):
    """Controller on dT/dt = (P*u - h*(T - 25))/C, stepped exactly per control sample.

    u is the board's 7-bit soft-PWM fraction ``(out >> 1)/127``; the reading is T rounded to
    celsius_q5. Returns the temperatures (degC) seen at each sample.
    """
    ambient_c = 25.0
    dt_s = float(PID_DT_S)
    decay = math.exp(-loss_w_k / capacity_j_k * dt_s)
    ctl = FuzzyPi(config)
    temp_c, temps_c = ambient_c, []
    for k in range(int(duration_s / dt_s)):
        temp_q5 = round(temp_c * TEMP_ONE)
        temps_c.append(q5_to_c(temp_q5))
        out = ctl.update(temp_q5, setpoint_c, int(k * dt_s * 1000))
        final_c = ambient_c + power_w * (out >> 1) / SOFT_PWM_MAX / loss_w_k
        temp_c = final_c + (temp_c - final_c) * decay
    return temps_c


@pytest.mark.parametrize(
    "config, setpoint_c, plant, duration_s, reach_s, overshoot_c",
    [
        # 40 W cartridge in a 17 J/K block (2.35 C/s at full power), 0.1 W/K to the room:
        # full power alone would need ~110 s to reach 214 C.
        (SEED004_HOTEND, SEED004_HOTEND_SETPOINT_C, (17.0, 40.0, 0.1), 400, 150, 3.0),
        # MK3 bed: 90 W at 220/255 (104 W at 255), 400 J/K, 0.55 W/K: ~480 s to 105 C at full power.
        (SEED004_BED, SEED004_BED_SETPOINT_C, (400.0, 104.0, 0.55), 1500, 600, 1.5),
    ],
)
def test_closed_loop_reaches_and_holds(config, setpoint_c, plant, duration_s, reach_s, overshoot_c):
    """Heats to within 1 C of the setpoint in reach_s, overshoots less than overshoot_c, and
    holds within 0.25 C (8 steps of the reading) over the last third of the run."""
    temps_c = run_first_order(config, setpoint_c, *plant, duration_s)
    dt_s = float(PID_DT_S)
    reached = next(k for k, t in enumerate(temps_c) if t >= setpoint_c - 1.0)
    assert reached * dt_s < reach_s
    assert max(temps_c) < setpoint_c + overshoot_c
    tail = temps_c[2 * len(temps_c) // 3:]
    assert max(abs(t - setpoint_c) for t in tail) <= 0.25
