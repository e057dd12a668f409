"""Thermal protection: runaway, heating watch, MIN/MAXTEMP thresholds and the exact error text."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.marlin.protection import (
    H_BED,
    HeaterWatch,
    RunawayMonitor,
    RunawayState,
    TempError,
    TempRange,
    heater_on,
    kill_text,
    m112_text,
    temp_error_text,
)
from firmware_port.thermistor import B3950_TABLE, MAX_RAW_THERMISTOR_VALUE, OVERSAMPLENR, TempTable

ONE = 32  # celsius_q5 per degree


def q5(temp_c: float) -> int:
    return round(temp_c * ONE)


# --- runaway ---------------------------------------------------------------------------------


def test_runaway_factory_defaults():
    assert (RunawayMonitor.hotend().period_s, RunawayMonitor.hotend().hysteresis_c) == (40, 4)
    assert (RunawayMonitor.bed().period_s, RunawayMonitor.bed().hysteresis_c) == (20, 2)


def test_runaway_never_trips_while_first_heating():
    mon = RunawayMonitor.hotend()
    for now_ms in range(0, 3_600_000, 164):  # an hour stuck at 100 C under a 200 C target
        assert not mon.run(q5(100), 200, now_ms)
    assert mon.state is RunawayState.FIRST_HEATING


def test_runaway_trips_exactly_one_period_after_last_good_sample():
    mon = RunawayMonitor.hotend()
    assert not mon.run(q5(200), 200, 1_000)  # reaches target: falls into Stable, timer = 41 000
    assert mon.state is RunawayState.STABLE
    too_cold = q5(196) - 1  # 1/32 C below target - hysteresis
    assert not mon.run(too_cold, 200, 2_000)
    assert not mon.run(too_cold, 200, 40_999)
    assert mon.run(too_cold, 200, 41_000)
    assert mon.state is RunawayState.RUNAWAY
    assert mon.run(too_cold, 200, 41_164)  # the C switch keeps calling _temp_error


def test_runaway_boundary_temperature_keeps_it_alive():
    mon = RunawayMonitor.hotend()
    mon.run(q5(200), 200, 0)
    for now_ms in range(0, 200_000, 1_000):
        assert not mon.run(q5(196), 200, now_ms)  # exactly target - hysteresis is fine


def test_runaway_rearms_on_target_change():
    mon = RunawayMonitor.hotend()
    mon.run(q5(200), 200, 0)
    mon.run(q5(180), 200, 1_000)
    assert not mon.run(q5(180), 210, 39_000)  # new target: back to first heating, no timeout
    assert mon.state is RunawayState.FIRST_HEATING
    assert not mon.run(q5(180), 210, 500_000)
    assert not mon.run(q5(180), 0, 500_164)
    assert mon.state is RunawayState.INACTIVE


def test_runaway_timer_survives_millis_wrap():
    mon = RunawayMonitor.bed()
    start_ms = 2**32 - 10_000
    mon.run(q5(60), 60, start_ms)  # timer wraps to 10 000
    assert mon.timer_ms == 10_000
    assert not mon.run(q5(50), 60, 2**32 + 9_999)
    assert mon.run(q5(50), 60, 2**32 + 10_000)


@given(
    target_c=st.integers(1, 300),
    hysteresis_c=st.integers(1, 10),
    period_s=st.integers(1, 120),
    samples=st.lists(
        st.tuples(st.integers(0, 200_000), st.integers(0, 64 * ONE)), max_size=60
    ),
)
def test_runaway_never_trips_at_or_above_target_minus_hysteresis(
    target_c, hysteresis_c, period_s, samples
):
    mon = RunawayMonitor(period_s, hysteresis_c)
    now_ms = 0
    for gap_ms, above_q5 in samples:
        now_ms += gap_ms
        assert not mon.run((target_c - hysteresis_c) * ONE + above_q5, target_c, now_ms)


@given(
    target_c=st.integers(1, 300),
    hysteresis_c=st.integers(1, 10),
    period_s=st.integers(1, 120),
    gaps_ms=st.lists(st.integers(1, 30_000), min_size=1, max_size=60),
)
def test_runaway_trips_at_first_sample_a_period_after_last_good_one(
    target_c, hysteresis_c, period_s, gaps_ms
):
    mon = RunawayMonitor(period_s, hysteresis_c)
    mon.run(target_c * ONE, target_c, 0)
    now_ms = 0
    for gap_ms in gaps_ms:
        now_ms += gap_ms
        tripped = mon.run((target_c - hysteresis_c) * ONE - 1, target_c, now_ms)
        assert tripped == (now_ms >= period_s * 1000)
        if now_ms >= period_s * 1000:
            break


# --- heating watch ---------------------------------------------------------------------------


def test_watch_factory_defaults():
    hotend, bed = HeaterWatch.hotend(), HeaterWatch.bed()
    assert (hotend.increase_c, hotend.hysteresis_c, hotend.period_s) == (2, 3, 40)
    assert (bed.increase_c, bed.hysteresis_c, bed.period_s) == (2, 3, 60)


def test_watch_arms_only_below_target_minus_6():
    watch = HeaterWatch.hotend()
    watch.restart(q5(193.97), 200, 0)  # truncated to 193: 195 < 196
    assert watch.next_ms == 40_000 and watch.target_c == 195
    watch.restart(q5(194), 200, 0)  # 196 < 196 fails: disabled
    assert watch.next_ms == 0
    assert not watch.heating_failed(q5(20), 200, 10**6)
    watch.restart(q5(20), 0, 0)  # target 0: disabled
    assert watch.next_ms == 0


def test_watch_trips_when_rise_too_slow():
    watch = HeaterWatch.hotend()
    watch.restart(q5(20), 200, 0)
    assert not watch.heating_failed(q5(20), 200, 39_999)
    assert watch.heating_failed(q5(21.97), 200, 40_000)  # 21.97 truncates to 21 < 22


def test_watch_rearms_from_current_temperature_when_fast_enough():
    watch = HeaterWatch.hotend()
    watch.restart(q5(20), 200, 0)
    assert not watch.heating_failed(q5(30.5), 200, 40_100)
    assert (watch.target_c, watch.next_ms) == (32, 80_100)
    assert watch.heating_failed(q5(31.9), 200, 80_100)


def test_watch_truncates_toward_zero():
    watch = HeaterWatch.bed()
    watch.restart(q5(-0.5), 60, 0)  # celsius_t(-0.5) == 0, not -1
    assert watch.target_c == 2
    assert not watch.check(q5(1.97))
    assert watch.check(q5(2))


def test_bed_watch_period_is_60_s():
    watch = HeaterWatch.bed()
    watch.restart(q5(25), 100, 0)
    assert not watch.heating_failed(q5(25), 100, 59_999)
    assert watch.heating_failed(q5(25), 100, 60_000)


@given(
    start_c=st.integers(0, 150),
    target_c=st.integers(1, 300),
    extra_q5=st.lists(st.integers(0, 64), max_size=100),
    gaps_ms=st.lists(st.integers(1, 50_000), min_size=1, max_size=100),
)
def test_watch_never_trips_when_rising_at_least_increase_per_period(
    start_c, target_c, extra_q5, gaps_ms
):
    watch = HeaterWatch.hotend()
    rate_q5_per_ms = watch.increase_c * ONE / (watch.period_s * 1000)
    watch.restart(start_c * ONE, target_c, 0)
    now_ms, bonus_q5 = 0, 0
    for i, gap_ms in enumerate(gaps_ms):
        now_ms += gap_ms
        bonus_q5 += extra_q5[i] if i < len(extra_q5) else 0
        temp_q5 = start_c * ONE + math.ceil(rate_q5_per_ms * now_ms) + bonus_q5
        assert not watch.heating_failed(temp_q5, target_c, now_ms)


@given(
    start_c=st.integers(0, 150),
    margin_c=st.integers(7, 150),
    gaps_ms=st.lists(st.integers(1, 20_000), min_size=1),
)
def test_watch_trips_at_first_sample_past_deadline_when_flat(start_c, margin_c, gaps_ms):
    watch = HeaterWatch.hotend()
    watch.restart(start_c * ONE, start_c + margin_c + 1, 0)
    now_ms = 0
    for gap_ms in gaps_ms:
        now_ms += gap_ms
        failed = watch.heating_failed(start_c * ONE + ONE - 1, start_c + margin_c + 1, now_ms)
        assert failed == (now_ms >= 40_000)
        if now_ms >= 40_000:
            break


# --- MINTEMP / MAXTEMP -----------------------------------------------------------------------


def test_hotend_range_b3950():
    rng = TempRange.hotend(B3950_TABLE)
    assert (rng.mintemp_c, rng.maxtemp_c, rng.max_target_c) == (5, 275, 260)
    lookup = B3950_TABLE.lookup_q5
    # raw_max: stepped up from raw 0 by OVERSAMPLENR until the reading is no longer above 275 C.
    assert rng.raw_max % OVERSAMPLENR == 0
    assert lookup(rng.raw_max) <= 275 * ONE < lookup(rng.raw_max - OVERSAMPLENR)
    assert abs(lookup(rng.raw_max) - 275 * ONE) < 2 * ONE
    # raw_min: stepped down from 16383 until the reading is no longer below 5 C.
    assert (MAX_RAW_THERMISTOR_VALUE - rng.raw_min) % OVERSAMPLENR == 0
    assert lookup(rng.raw_min) >= 5 * ONE > lookup(rng.raw_min + OVERSAMPLENR)
    assert abs(lookup(rng.raw_min) - 5 * ONE) < 2 * ONE


def test_bed_range_b3950():
    rng = TempRange.bed(B3950_TABLE)
    assert (rng.mintemp_c, rng.maxtemp_c, rng.max_target_c) == (5, 150, 140)
    lookup = B3950_TABLE.lookup_q5
    assert lookup(rng.raw_max) <= 150 * ONE < lookup(rng.raw_max - OVERSAMPLENR)


def test_hotend_limits_narrowed_to_table_bed_not():
    table = TempTable(raw=(1000, 8000, 16000), temp_q5=(q5(250.5), q5(100), q5(10.75)))
    hotend = TempRange.hotend(table)
    assert (hotend.mintemp_c, hotend.maxtemp_c) == (10, 249)
    assert hotend.max_target_c == 260  # from HEATER_0_MAXTEMP, as Marlin's hotend_max_target
    bed = TempRange(table, 5, 275, overshoot_c=10, limit_to_table=False)
    assert (bed.mintemp_c, bed.maxtemp_c) == (5, 275)


def test_open_thermistor_trips_mintemp_only_when_heating():
    rng = TempRange.hotend(B3950_TABLE)
    open_raw = 16 * 1023
    assert rng.mintemp_raw_tripped(open_raw, heater_on=True)
    assert not rng.mintemp_raw_tripped(open_raw, heater_on=False)
    assert not rng.maxtemp_raw_tripped(open_raw)


def test_shorted_thermistor_trips_maxtemp():
    for rng in (TempRange.hotend(B3950_TABLE), TempRange.bed(B3950_TABLE)):
        assert rng.maxtemp_raw_tripped(0)
        assert not rng.mintemp_raw_tripped(0, heater_on=True)


def test_raw_thresholds_are_strict():
    rng = TempRange.hotend(B3950_TABLE)
    assert not rng.maxtemp_raw_tripped(rng.raw_max)
    assert rng.maxtemp_raw_tripped(rng.raw_max - 1)
    assert not rng.mintemp_raw_tripped(rng.raw_min, heater_on=True)
    assert rng.mintemp_raw_tripped(rng.raw_min + 1, heater_on=True)


def test_maxtemp_on_converted_temperature():
    rng = TempRange.hotend(B3950_TABLE)
    assert not rng.maxtemp_tripped(275 * ONE)
    assert rng.maxtemp_tripped(275 * ONE + 1)


def test_clamp_target():
    hotend, bed = TempRange.hotend(B3950_TABLE), TempRange.bed(B3950_TABLE)
    assert [hotend.clamp_target(t) for t in (300, 260, 200)] == [260, 260, 200]
    assert [bed.clamp_target(t) for t in (150, 60, 0)] == [140, 60, 0]


def test_heater_on_by_version():
    assert heater_on(200) and not heater_on(0) and not heater_on(0, soft_pwm_amount=50)
    assert heater_on(0, soft_pwm_amount=50, version="2.0")
    assert not heater_on(0, soft_pwm_amount=0, version="2.0")
    with pytest.raises(ValueError):
        heater_on(200, version="1.1")


# --- error text ------------------------------------------------------------------------------

HALTED = b"Error:Printer halted. kill() called!\n"


@pytest.mark.parametrize(
    "kind, lcd",
    [
        ("Thermal Runaway", b"THERMAL RUNAWAY"),
        ("Heating failed", b"Heating Failed"),
        ("MAXTEMP triggered", b"Err: MAXTEMP"),
        ("MINTEMP triggered", b"Err: MINTEMP"),
    ],
)
def test_error_text_21(kind, lcd):
    head = b"Error:" + kind.encode() + b", system stopped! Heater_ID: "
    kill = b"echo:" + lcd + b"\n" + HALTED
    assert temp_error_text(kind, 0).encode() == head + b"E0\n\n" + kill
    assert temp_error_text(kind, H_BED).encode() == head + b"bed\n" + kill


@pytest.mark.parametrize("kind", list(TempError))
def test_error_text_20(kind):
    head = b"Error:" + kind.value.encode() + b", system stopped! Heater_ID: "
    assert temp_error_text(kind, 0, version="2.0").encode() == head + b"0\n" + HALTED
    assert temp_error_text(kind, H_BED, version="2.0").encode() == head + b"bed\n" + HALTED


def test_thermal_runaway_hotend_full_text():
    assert temp_error_text(TempError.THERMAL_RUNAWAY, 0) == (
        "Error:Thermal Runaway, system stopped! Heater_ID: E0\n"
        "\n"
        "echo:THERMAL RUNAWAY\n"
        "Error:Printer halted. kill() called!\n"
    )


def test_kill_and_m112_text():
    assert m112_text().encode() == b"echo:M112 Shutdown\n" + HALTED
    assert m112_text(version="2.0").encode() == HALTED
    assert kill_text(None).encode() == HALTED


def test_error_text_rejects_unknown_input():
    with pytest.raises(ValueError):
        temp_error_text("Cooling failed", 0)
    with pytest.raises(ValueError):
        temp_error_text(TempError.MAXTEMP, -2)
    with pytest.raises(ValueError):
        temp_error_text(TempError.MAXTEMP, 0, version="2.2")
