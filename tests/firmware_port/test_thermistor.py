"""Property 5: the B3950 table and its integer lookup; the thermistor physics."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.thermistor import (
    B3950,
    B3950_TABLE,
    KLIPPER_SENSORS,
    MAX_RAW_THERMISTOR_VALUE,
    RAW_MAX,
    TABLE_ERROR_BOUND_C,
    TEMP_ONE,
    Divider,
    SteinhartHart,
    TempTable,
)

DIVIDER = Divider()
raw_any = st.integers(min_value=0, max_value=MAX_RAW_THERMISTOR_VALUE)
# raw values whose exact temperature lies in 20..280 C
RAW_280 = math.ceil(16 * DIVIDER.adc_exact(280.0))
RAW_20 = math.floor(16 * DIVIDER.adc_exact(20.0))


@pytest.mark.parametrize(
    "temp_c, adc10",
    [(25, 978.0), (100, 611.8), (150, 305.3), (200, 140.0), (250, 68.2), (300, 36.5)],
)
def test_beta_divider_matches_marlin_type_11_check_values(temp_c, adc10):
    # Marlin 2.1.x Marlin/src/module/thermistor/thermistors.h: the beta model with a 4.7k pull-up regenerates table 11
    assert round(DIVIDER.adc_exact(temp_c), 1) == adc10


def test_the_stored_table_is_the_one_generate_builds():
    # firmware_port/thermistor.py keeps B3950_TABLE as constants (start-up time); they must be what the
    # generator gives for the default divider and tolerance, row for row
    assert TempTable.generate() == B3950_TABLE


def test_table_is_strictly_monotone_and_fits_int16():
    t = B3950_TABLE
    assert all(a < b for a, b in zip(t.raw, t.raw[1:]))
    assert all(a > b for a, b in zip(t.temp_q5, t.temp_q5[1:]))
    assert t.raw[0] == 16 and t.raw[-1] == 1021 * 16  # OV(1) .. OV(1021), as type 11
    assert t.flash_bytes == 4 * len(t.raw)


@given(raw_any, raw_any)
def test_lookup_is_monotone_in_raw(a, b):
    lo, hi = sorted((a, b))
    assert B3950_TABLE.lookup_q5(lo) >= B3950_TABLE.lookup_q5(hi)


@given(st.integers(min_value=RAW_280, max_value=RAW_20))
def test_lookup_error_against_the_exact_beta_curve(raw):
    """Bound: 0.05 C breakpoint tolerance + 1/64 C row rounding + 1/64 C division rounding."""
    exact = DIVIDER.temp_at_raw(raw)
    assert abs(B3950_TABLE.lookup_q5(raw) / TEMP_ONE - exact) <= TABLE_ERROR_BOUND_C


def test_lookup_error_bound_holds_on_every_raw_value_20_to_280_c():
    worst = max(
        abs(B3950_TABLE.lookup_q5(raw) / TEMP_ONE - DIVIDER.temp_at_raw(raw)) for raw in range(RAW_280, RAW_20 + 1)
    )
    assert worst <= TABLE_ERROR_BOUND_C


@given(raw_any)
def test_integer_lookup_agrees_with_marlin_float_interpolation(raw):
    # Only the final rounding differs: at most half a Q10.5 step plus float32 rounding.
    assert abs(B3950_TABLE.lookup_q5(raw) / TEMP_ONE - float(B3950_TABLE.lookup_f32(raw))) <= 1 / 64 + 1e-4


@given(st.integers(min_value=-100, max_value=15))
def test_raw_below_the_table_reads_the_hottest_row(raw):
    assert B3950_TABLE.lookup_q5(max(raw, 0)) == B3950_TABLE.temp_q5[0]


@given(st.integers(min_value=1021 * 16, max_value=MAX_RAW_THERMISTOR_VALUE))
def test_raw_above_the_table_reads_the_coldest_row(raw):
    assert B3950_TABLE.lookup_q5(raw) == B3950_TABLE.temp_q5[-1]


def test_open_and_shorted_thermistor_readings():
    assert B3950_TABLE.lookup_q5(RAW_MAX) / TEMP_ONE < 0  # open: reads the coldest row
    assert B3950_TABLE.lookup_q5(0) / TEMP_ONE > 900  # shorted: reads the hottest row (type 11: 938)


@given(st.floats(min_value=-20, max_value=400))
def test_beta_resistance_and_temperature_are_inverse(temp_c):
    assert B3950.temp_c(B3950.resistance_ohm(temp_c)) == pytest.approx(temp_c, abs=1e-9)


@pytest.mark.parametrize("name", sorted(KLIPPER_SENSORS))
def test_klipper_sensors_pass_through_their_defining_points(name):
    part = KLIPPER_SENSORS[name]
    for temp_c in (25.0, 150.0, 250.0):
        assert part.temp_c(part.resistance_ohm(temp_c)) == pytest.approx(temp_c, abs=1e-6)
    assert part.resistance_ohm(25.0) > part.resistance_ohm(150.0)


def test_steinhart_hart_from_points_reproduces_the_points():
    part = KLIPPER_SENSORS["EPCOS 100K B57560G104F"]
    for temp_c, r in ((25, 100000), (150, 1641.9), (250, 226.15)):
        assert part.temp_c(r) == pytest.approx(temp_c, abs=1e-9)
    with pytest.raises(ValueError, match="three"):
        SteinhartHart.from_points(((25, 100000), (150, 1641.9)))


def test_table_for_another_part_and_pullup():
    table = TempTable.generate(Divider(KLIPPER_SENSORS["ATC Semitec 104GT-2"], pullup_ohm=2200.0))
    d = Divider(KLIPPER_SENSORS["ATC Semitec 104GT-2"], 2200.0)
    raw = round(16 * d.adc_exact(210.0))
    assert abs(table.lookup_q5(raw) / TEMP_ONE - 210.0) < 0.2


def test_table_rejects_values_that_do_not_fit_int16():
    with pytest.raises(ValueError, match="int16"):
        TempTable((0, 40000), (100, 0))
