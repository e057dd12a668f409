"""twin.metrics: analytic responses, symmetries, irregular sampling, disturbances, validation."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from twin.metrics import (
    LIMIT_CYCLE_READING_STEPS,
    LimitCycle,
    StepMetrics,
    format_metrics_table,
    limit_cycle,
    limit_cycles,
    max_deviation_c,
    recovery_time_s,
    segments,
    step_metrics,
)


def first_order(t, start_c, step_c, tau_s):
    return start_c + step_c * (1 - np.exp(-t / tau_s))


def second_order(t, start_c, step_c, zeta, wn):
    """Unit step response of wn^2 / (s^2 + 2 zeta wn s + wn^2), 0 < zeta < 1, scaled to the step."""
    wd = wn * math.sqrt(1 - zeta**2)
    y = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))
    return start_c + step_c * y


def assert_metrics_close(a: StepMetrics, b: StepMetrics, abs_tol: float = 1e-6, rel_tol: float = 1e-9):
    for field in dataclasses.fields(StepMetrics):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if x is None or y is None or isinstance(x, bool):
            assert x == y, field.name
        else:
            assert x == pytest.approx(y, rel=rel_tol, abs=abs_tol), field.name


# --- analytic responses ---------------------------------------------------------------------

T_FINE = np.arange(0, 300, 0.01)


def test_first_order_matches_closed_forms():
    tau, start, step = 20.0, 25.0, 175.0
    m = step_metrics(T_FINE, first_order(T_FINE, start, step, tau), start + step, duty=0.5)
    assert m.reached
    assert m.rise_time_s == pytest.approx(tau * math.log(9), abs=1e-3)
    assert m.settling_time_2pct_s == pytest.approx(tau * math.log(50), abs=1e-3)
    assert m.settling_time_5pct_s == pytest.approx(tau * math.log(20), abs=1e-3)
    assert m.time_to_band_s == pytest.approx(tau * math.log(step / 2.0), abs=1e-3)
    assert m.overshoot_c == 0.0 and m.overshoot_pct == 0.0 and m.peak_time_s is None
    # closed forms over [0, T]: IAE = D tau (1 - e^-T/tau), ITAE = D tau^2 (1 - (1 + T/tau) e^-T/tau)
    end = T_FINE[-1]
    assert m.iae_c_s == pytest.approx(step * tau * (1 - math.exp(-end / tau)), rel=1e-6)
    itae = step * tau**2 * (1 - (1 + end / tau) * math.exp(-end / tau))
    assert m.itae_c_s2 == pytest.approx(itae, rel=1e-6)
    assert m.steady_state_error_c == pytest.approx(0.0, abs=1e-3)


def test_second_order_underdamped_overshoot_and_peak():
    zeta, wn, start, step = 0.5, 0.1, 25.0, 175.0
    m = step_metrics(T_FINE, second_order(T_FINE, start, step, zeta, wn), start + step)
    expected_pct = 100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
    assert expected_pct == pytest.approx(16.3, abs=0.01)
    assert m.overshoot_pct == pytest.approx(expected_pct, abs=1e-4)
    assert m.overshoot_c == pytest.approx(step * expected_pct / 100, abs=1e-4)
    assert m.peak_time_s == pytest.approx(math.pi / (wn * math.sqrt(1 - zeta**2)), abs=0.01)
    # the envelope bounds the settling time: |e| <= D e^(-zeta wn t) / sqrt(1 - zeta^2)
    assert m.settling_time_2pct_s <= math.log(50 / math.sqrt(1 - zeta**2)) / (zeta * wn)
    assert m.rise_time_s < m.peak_time_s < m.settling_time_2pct_s


def test_start_at_25_gives_the_rise_time_of_the_same_shape_from_0():
    tau = 20.0
    from_0 = step_metrics(T_FINE, first_order(T_FINE, 0.0, 175.0, tau), 175.0)
    from_25 = step_metrics(T_FINE, first_order(T_FINE, 25.0, 175.0, tau), 200.0)
    assert from_25.rise_time_s == pytest.approx(tau * math.log(9), abs=1e-3)
    assert_metrics_close(dataclasses.replace(from_25, start_c=0.0, target_c=175.0), from_0)
    # the pitfall, on a bed from 25 C to 60 C: thresholds at 10 % / 90 % of the final value (6 C and
    # 54 C) as if it started from 0 give tau ln(35/6) instead of tau ln 9, 20 % short
    bed = step_metrics(T_FINE, first_order(T_FINE, 25.0, 35.0, tau), 60.0)
    temp = first_order(T_FINE, 25.0, 35.0, tau)
    naive_rise_s = T_FINE[np.argmax(temp >= 54.0)] - T_FINE[np.argmax(temp >= 6.0)]
    assert bed.rise_time_s == pytest.approx(tau * math.log(9), abs=1e-3)
    assert naive_rise_s == pytest.approx(tau * math.log(35 / 6), abs=0.01)


def test_never_reached_is_none():
    t = np.arange(0, 200, 0.1)
    m = step_metrics(t, first_order(t, 25.0, 155.0, 10.0), 200.0)  # levels off 20 C short
    assert not m.reached
    assert m.rise_time_s is None and m.time_to_band_s is None
    assert m.settling_time_2pct_s is None and m.settling_time_5pct_s is None
    assert m.overshoot_c == 0.0 and m.peak_time_s is None
    assert m.steady_state_error_c == pytest.approx(20.0, abs=1e-3)


def test_zero_step_keeps_the_absolute_metrics():
    t = np.arange(0, 60, 0.5)
    temp = 200.0 + np.where(t >= 10, np.sin(t), 0.0)  # starts exactly at the target
    m = step_metrics(t, temp, 200.0, duty=0.2)
    assert m.rise_time_s is m.overshoot_c is m.overshoot_pct is m.peak_time_s is None
    assert m.settling_time_2pct_s is m.settling_time_5pct_s is None
    assert m.reached and m.time_to_band_s == 0.0
    assert m.iae_c_s > 0 and m.itae_c_s2 > 0
    assert m.duty_sq_s == pytest.approx(0.04 * t[-1])


# --- integrals ------------------------------------------------------------------------------


def test_constant_duty_integral_is_d_squared_times_duration():
    t = np.cumsum(np.random.default_rng(1).uniform(0.5, 1.5, 300))
    m = step_metrics(t, np.full(t.size, 100.0), 200.0, duty=0.7)
    assert m.duty_sq_s == pytest.approx(0.49 * (t[-1] - t[0]))


def test_duty_integral_holds_each_value_until_the_next_sample():
    t = np.array([0.0, 1.0, 3.0, 6.0])
    m = step_metrics(t, [20.0, 21.0, 23.0, 26.0], 200.0, duty=[1.0, 0.0, 0.5, 1.0])
    assert m.duty_sq_s == pytest.approx(1.0 * 1 + 0.0 * 2 + 0.25 * 3)  # the last sample adds nothing


def test_iae_itae_of_a_constant_error_from_the_step_start():
    t = np.arange(0, 160.5, 0.5)
    target = np.where(t < 100, 180.0, 200.0)
    m = step_metrics(t, np.full(t.size, 190.0), target, start_s=100.0)
    assert m.iae_c_s == pytest.approx(10 * 60)
    assert m.itae_c_s2 == pytest.approx(10 * 60**2 / 2)  # t counted from start_s, not from 0
    assert m.steady_state_error_c == pytest.approx(10.0)


def test_iae_itae_of_a_linear_error():
    t = np.arange(0, 50.005, 0.01)
    m = step_metrics(t, 150.0 + t, 200.0)  # e = 50 - t
    assert m.iae_c_s == pytest.approx(50**2 / 2, rel=1e-9)
    assert m.itae_c_s2 == pytest.approx(50**3 / 6, rel=1e-6)


def test_steady_window_is_capped_at_a_tenth_of_the_segment():
    t = np.arange(0, 100.5, 0.5)
    temp = np.where(t < 90, 190.0, 199.0)  # the last 10 s are 1 C short
    assert step_metrics(t, temp, 200.0).steady_state_error_c == pytest.approx(1.0)
    long_t = np.arange(0, 1000.5, 0.5)
    long_temp = np.where(long_t < 970, 190.0, 199.0)  # the last 30 s are 1 C short
    assert step_metrics(long_t, long_temp, 200.0).steady_state_error_c == pytest.approx(1.0)


# --- symmetries and sampling ----------------------------------------------------------------

responses = st.fixed_dictionaries(
    {
        "start_c": st.floats(-50, 300),
        "step_c": st.floats(1, 250) | st.floats(-250, -1),
        "zeta": st.floats(0.2, 0.95) | st.none(),  # None: first order
        "time_constant_s": st.floats(2, 60),
        "duty": st.floats(0, 1),
    }
)


def response(t, r):
    if r["zeta"] is None:
        return first_order(t, r["start_c"], r["step_c"], r["time_constant_s"])
    return second_order(t, r["start_c"], r["step_c"], r["zeta"], 1 / r["time_constant_s"])


def grid(r):
    """10 time constants (of the envelope, for second order) in 2000 samples."""
    return np.linspace(0, 10 * r["time_constant_s"] / (r["zeta"] or 1), 2000)


@given(responses)
def test_cooling_mirrors_heating(r):
    t = grid(r)
    temp = response(t, r)
    target = r["start_c"] + r["step_c"]
    m = step_metrics(t, temp, target, r["duty"])
    mirrored = step_metrics(t, -temp, -target, r["duty"])
    steady = None if m.steady_state_error_c is None else -m.steady_state_error_c
    expected = dataclasses.replace(m, start_c=-m.start_c, target_c=-m.target_c, steady_state_error_c=steady)
    assert_metrics_close(mirrored, expected)


@given(responses, st.floats(-100, 100))
def test_shifting_both_temperatures_changes_nothing_relative(r, shift_c):
    t = grid(r)
    temp = response(t, r)
    target = r["start_c"] + r["step_c"]
    m = step_metrics(t, temp, target, r["duty"])
    shifted = step_metrics(t, temp + shift_c, target + shift_c, r["duty"])
    expected = dataclasses.replace(m, start_c=m.start_c + shift_c, target_c=m.target_c + shift_c)
    assert_metrics_close(shifted, expected, abs_tol=1e-6, rel_tol=1e-6)


@given(st.integers(0, 2**32 - 1), st.sampled_from([None, 0.5, 0.7]))
def test_irregular_1hz_sampling_is_close_to_fine_sampling(seed, zeta):
    """Klipper-like Stats: 0.5..1.5 s between samples, on hotend-like time scales."""
    r = {"start_c": 25.0, "step_c": 175.0, "zeta": zeta, "time_constant_s": 40.0}
    t_log = np.concatenate([[0.0], np.cumsum(np.random.default_rng(seed).uniform(0.5, 1.5, 600))])
    t_fine = np.arange(0, t_log[-1], 0.02)
    log = step_metrics(t_log, response(t_log, r), 200.0)
    fine = step_metrics(t_fine, response(t_fine, r), 200.0)
    for name, tol in (
        ("rise_time_s", 0.05),
        ("time_to_band_s", 0.05),
        ("settling_time_2pct_s", 0.05),
        ("settling_time_5pct_s", 0.05),
        ("overshoot_c", 0.02),
        ("steady_state_error_c", 0.005),
    ):
        assert getattr(log, name) == pytest.approx(getattr(fine, name), abs=tol), name
    assert log.iae_c_s == pytest.approx(fine.iae_c_s, rel=5e-4)
    assert log.itae_c_s2 == pytest.approx(fine.itae_c_s2, rel=5e-4)


# --- disturbances ---------------------------------------------------------------------------

T_DIP = np.arange(0, 200.5, 0.5)


def dip(t, depth_c=10.0, end_s=130.0):
    """At 200 C, a linear fall to 200 - depth at 110 s after a kick at 100 s, back at end_s."""
    return 200.0 - depth_c * np.interp(t, [100.0, 110.0, end_s], [0.0, 1.0, 0.0])


def test_recovery_after_a_dip():
    temp = dip(T_DIP)
    assert recovery_time_s(T_DIP, temp, 200.0, 100.0) == pytest.approx(26.0)  # back above 198 C at 126 s
    assert recovery_time_s(T_DIP, temp, 200.0, 100.0, band_c=5.0) == pytest.approx(20.0)
    assert max_deviation_c(T_DIP, temp, 200.0, 100.0) == pytest.approx(10.0)


def test_recovery_is_none_until_back_and_zero_if_never_out():
    assert recovery_time_s(T_DIP, dip(T_DIP, end_s=400.0), 200.0, 100.0) is None
    assert recovery_time_s(T_DIP, dip(T_DIP, depth_c=1.5), 200.0, 100.0) == 0.0


def test_disturbance_after_the_trace_is_an_error():
    with pytest.raises(ValueError, match="disturbance_s"):
        max_deviation_c(T_DIP, dip(T_DIP), 200.0, 500.0)


# --- segments -------------------------------------------------------------------------------


def test_segments_split_at_each_target_change_and_give_cooling_steps():
    t = np.arange(0, 600, 0.5)
    target = np.select([t < 200, t < 400], [200.0, 60.0], 200.0)
    temp = np.empty_like(t)
    start_c = 25.0
    for a, b in ((0, 200), (200, 400), (400, 600)):
        part = (t >= a) & (t < b)
        temp[part] = first_order(t[part] - a, start_c, target[part][0] - start_c, 15.0)
        start_c = temp[part][-1]

    parts = segments(t, target)
    assert parts == [(0.0, 200.0), (200.0, 400.0), (400.0, math.inf)]
    heat, cool, reheat = (step_metrics(t, temp, target, start_s=a, end_s=b) for a, b in parts)
    assert heat.start_c == 25.0 and heat.reached
    assert cool.target_c == 60.0 and cool.start_c == pytest.approx(200.0, abs=1e-3)
    assert cool.rise_time_s == pytest.approx(15 * math.log(9), abs=0.01)
    assert reheat.settling_time_2pct_s == pytest.approx(15 * math.log(50), abs=0.01)


def test_segments_needs_a_target_per_sample():
    with pytest.raises(ValueError, match="target_c must be a 1-D array as long as t_s"):
        segments([0.0, 1.0, 2.0], [200.0, 60.0])


# --- validation -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"t_s": [0.0, 2.0, 1.0]}, "strictly increasing"),
        ({"t_s": [0.0, 1.0, 1.0]}, "strictly increasing"),
        ({"temp_c": [20.0, 30.0]}, "temp_c must be a 1-D array as long as t_s"),
        ({"target_c": [200.0, 200.0]}, "target_c must be"),
        ({"t_s": [[0.0, 1.0, 2.0]]}, "t_s must be a 1-D array"),
        ({"temp_c": [20.0, math.nan, 40.0]}, "NaN"),
        ({"target_c": [200.0, 200.0, 60.0]}, "target_c changes inside the segment"),
        ({"duty": [0.5, 1.5, 0.0]}, "duty must be within 0..1"),
        ({"start_s": 2.0}, "fewer than 2 samples"),
        ({"band_c": 0.0}, "must be positive"),
    ],
)
def test_bad_inputs_raise(kwargs, message):
    args = {"t_s": [0.0, 1.0, 2.0], "temp_c": [20.0, 30.0, 40.0], "target_c": 200.0} | kwargs
    with pytest.raises(ValueError, match=message):
        step_metrics(**args)


# --- table ----------------------------------------------------------------------------------


def test_table_is_stable_and_shows_none_as_a_dash():
    heat = StepMetrics(
        start_c=25.0, target_c=200.0, reached=True, rise_time_s=21.972, time_to_band_s=44.716,
        overshoot_c=3.5, overshoot_pct=2.0, peak_time_s=61.25, settling_time_2pct_s=39.12,
        settling_time_5pct_s=29.957, steady_state_error_c=-0.001, limit_cycle_amplitude_c=None,
        limit_cycle_period_s=None, iae_c_s=1749.95, itae_c_s2=17493.644, duty_sq_s=100.0,
    )
    cool = dataclasses.replace(
        heat, start_c=200.0, target_c=60.0, reached=False, rise_time_s=None, time_to_band_s=None,
        overshoot_c=0.0, overshoot_pct=0.0, peak_time_s=None, settling_time_2pct_s=None,
        settling_time_5pct_s=None, steady_state_error_c=-120.0, duty_sq_s=None,
    )
    cycling = dataclasses.replace(heat, settling_time_2pct_s=None, steady_state_error_c=None,
                                  limit_cycle_amplitude_c=10.534, limit_cycle_period_s=78.479)
    assert format_metrics_table([heat, cool, cycling]) == "\n".join(
        [
            "metric                     step 1    step 2    step 3",
            "start_c                     25.00    200.00     25.00",
            "target_c                   200.00     60.00    200.00",
            "reached                       yes        no       yes",
            "rise_time_s                 21.97         -     21.97",
            "time_to_band_s              44.72         -     44.72",
            "overshoot_c                  3.50      0.00      3.50",
            "overshoot_pct                2.00      0.00      2.00",
            "peak_time_s                 61.25         -     61.25",
            "settling_time_2pct_s        39.12         -         -",
            "settling_time_5pct_s        29.96         -     29.96",
            "steady_state_error_c         0.00   -120.00         -",
            "limit_cycle_amplitude_c         -         -     10.53",
            "limit_cycle_period_s            -         -     78.48",
            "iae_c_s                   1749.95   1749.95   1749.95",
            "itae_c_s2                17493.64  17493.64  17493.64",
            "duty_sq_s                  100.00         -    100.00",
        ]
    )
    assert format_metrics_table(heat) == format_metrics_table([heat])


# --- limit cycles ---------------------------------------------------------------------------

T_HOLD = np.arange(0, 900, 0.164)  # Marlin's readings, 15 min


def heat_then_cycle(t, amplitude_c, period_s, growth_per_s=0.0, target_c=240.0):
    """25 C -> target_c (40 s time constant), an oscillation about the target fading in as the heat-up ends."""
    approach = first_order(t, 25.0, target_c - 25.0, 40.0)
    swing = amplitude_c * np.exp(growth_per_s * t) * np.sin(2 * np.pi * t / period_s)
    return approach + swing * (1 - np.exp(-t / 40.0))


def quantised(temp_c, step_c):
    return np.round(temp_c / step_c) * step_c


@pytest.mark.parametrize("step_c", [0.0, 0.8])
def test_a_limit_cycle_gives_its_amplitude_and_period_and_no_steady_state(step_c):
    """+-10 C every 80 s about 240 C (the cartridge at 240 C on the twin), read raw or in 0.8 C steps (the
    10-bit ADC there) with 0.2 C of noise."""
    temp = heat_then_cycle(T_HOLD, 10.0, 80.0) + np.random.default_rng(1).normal(0, 0.2, T_HOLD.size)
    temp = quantised(temp, step_c) if step_c else temp
    cycle = limit_cycle(T_HOLD, temp, 240.0)
    assert cycle is not None and cycle.cycles >= 8
    assert cycle.amplitude_c == pytest.approx(10.0, abs=0.7) and cycle.period_s == pytest.approx(80.0, abs=1.0)
    m = step_metrics(T_HOLD, temp, 240.0)
    assert m.reached and m.steady_state_error_c is None
    assert (m.limit_cycle_amplitude_c, m.limit_cycle_period_s) == (cycle.amplitude_c, cycle.period_s)


@pytest.mark.parametrize("noise_c, step_c", [(0.0, 0.0), (0.3, 0.0), (1.0, 0.0), (0.0, 0.8), (0.3, 0.8), (2.0, 0.8)])
def test_a_noisy_or_quantised_stable_hold_is_no_limit_cycle(noise_c, step_c):
    """A first-order heat-up held at 210 C, with Gaussian noise up to 1 C and readings in 0.8 C steps: never flagged,
    and the steady-state error is a number (several seeds: the thresholds are not tuned to one draw)."""
    for seed in range(5):
        temp = first_order(T_HOLD, 25.0, 185.0, 40.0) + np.random.default_rng(seed).normal(0, noise_c, T_HOLD.size)
        temp = quantised(temp, step_c) if step_c else temp
        assert limit_cycle(T_HOLD, temp, 210.0) is None
        assert step_metrics(T_HOLD, temp, 210.0).steady_state_error_c == pytest.approx(0.0, abs=0.5)  # 210 rounds to 209.6


def test_a_dither_of_one_reading_step_is_no_limit_cycle_but_several_steps_are():
    """Readings in 0.8 C steps: a slow cycle between two adjacent readings is as good a hold as a quantised
    loop gives; one reaching past LIMIT_CYCLE_READING_STEPS steps either side (the threshold) is a cycle."""
    wave = np.sin(2 * np.pi * T_HOLD / 60.0)
    assert limit_cycle(T_HOLD, 210.0 + 0.4 * np.sign(wave), 210.0) is None  # one step
    cycle = limit_cycle(T_HOLD, 210.0 + quantised(0.8 * (LIMIT_CYCLE_READING_STEPS + 1) * wave, 0.8), 210.0)
    assert cycle is not None and cycle.period_s == pytest.approx(60.0, abs=0.5)


@pytest.mark.parametrize("growth_per_s", [-0.02, 0.02])
def test_an_oscillation_that_decays_or_grows_is_not_sustained(growth_per_s):
    temp = heat_then_cycle(T_HOLD, 5.0, 80.0, growth_per_s)
    assert limit_cycle(T_HOLD, temp, 240.0) is None
    if growth_per_s < 0:
        assert step_metrics(T_HOLD, temp, 240.0).steady_state_error_c is not None


def test_one_that_stops_before_the_end_is_not_sustained():
    temp = np.where(T_HOLD < 500, heat_then_cycle(T_HOLD, 10.0, 80.0), 240.0)
    assert limit_cycle(T_HOLD, temp, 240.0) is None


def test_a_run_that_never_reaches_the_band_has_no_hold():
    assert limit_cycle(T_HOLD, heat_then_cycle(T_HOLD, 10.0, 80.0) - 50.0, 240.0) is None


def test_lanes_give_what_each_lane_gives_alone():
    """limit_cycles on (rows, lanes): the tuning layer's batch call, lane by lane the single-trace answer."""
    rng = np.random.default_rng(3)
    lanes = np.column_stack([heat_then_cycle(T_HOLD, 10.0, 80.0), first_order(T_HOLD, 25.0, 215.0, 40.0),
                             heat_then_cycle(T_HOLD, 3.0, 45.0) + rng.normal(0, 0.2, T_HOLD.size),
                             heat_then_cycle(T_HOLD, 10.0, 80.0) - 50.0])
    batch = limit_cycles(T_HOLD, lanes, 240.0)
    assert batch == [limit_cycle(T_HOLD, lanes[:, k], 240.0) for k in range(lanes.shape[1])]
    assert [isinstance(c, LimitCycle) for c in batch] == [True, False, True, False]


def test_limit_cycles_checks_its_inputs():
    with pytest.raises(ValueError, match=r"\(rows, lanes\)"):
        limit_cycles(T_HOLD, np.zeros(T_HOLD.size), 240.0)
    with pytest.raises(ValueError, match="target_c changes"):
        limit_cycles(T_HOLD, np.zeros((T_HOLD.size, 2)), np.where(T_HOLD < 100, 200.0, 210.0))
