"""Saved gains as PID_CALIBRATE's: any relay's Ku and Tu, through Klipper's rule and SAVE_CONFIG's three
decimals, are detected and give back their Ku and Tu within the rounding; gains off the relation by more than
their rounding explains are not; Klipper's example-config gains are no evidence; the klippy logs' own."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_port.klipper.pid_calibrate import zn_from_relay
from tools.tuning.calibration import detect, example_gains, from_config, half_unit

# Relays a printer's heater gives (README E: hotends Tu 5.4..57.6 s, beds 50..157 s; Kp 19..73 on the
# config scale): Ku on the 0..1 duty scale of Kp / 153, with room on both sides.
KU = st.floats(0.05, 1.0)
TU_S = st.floats(2.0, 400.0)
MAX_POWER = st.floats(0.3, 1.0)


def saved(ku: float, tu_s: float) -> tuple[str, str, str]:
    """What SAVE_CONFIG writes for the relay's gains: each "%.3f"."""
    return tuple(f"{g:.3f}" for g in zn_from_relay(ku, tu_s))  # type: ignore[return-value]


def test_half_unit_is_the_printed_rounding():
    assert half_unit("1.346") == pytest.approx(0.0005)
    assert half_unit("114") == 0.5 and half_unit("19.0") == pytest.approx(0.05)
    with pytest.raises(ValueError, match="not a number"):
        half_unit("fast")


@given(KU, TU_S)
@settings(max_examples=300, deadline=None)
def test_any_relay_is_detected_and_recovered_within_the_rounding(ku, tu_s):
    kp, ki, kd = saved(ku, tu_s)
    found = detect(kp, ki, kd)
    assert found is not None
    assert found.ku_range[0] <= ku <= found.ku_range[1]
    assert found.tu_range_s[0] <= tu_s * (1 + 1e-12) and tu_s <= found.tu_range_s[1] * (1 + 1e-12)
    assert found.tu_range_s[0] <= found.tu_s <= found.tu_range_s[1]
    # the range is the rounding's, no wider: three decimals of Kp and Ki bound Tu = 2 Kp / Ki
    width = 2.0 * (2.0 * 0.0005 / float(ki) + 2.0 * 0.0005 / float(kp)) * tu_s
    assert found.tu_range_s[1] - found.tu_range_s[0] <= width * 1.01 + 1e-9
    assert abs(found.ku - ku) <= 0.0005 / 153.0 * (1 + 1e-9)


@given(KU, TU_S, MAX_POWER)
@settings(max_examples=100, deadline=None)
def test_the_swing_follows_from_ku_and_max_power(ku, tu_s, max_power):
    found = detect(*saved(ku, tu_s))
    assert found is not None
    assert found.peak_to_peak_c(max_power) == pytest.approx(8.0 * max_power / (math.pi * ku), rel=1e-3)


@given(KU, TU_S, st.floats(0.02, 0.5), st.sampled_from([-1.0, 1.0]))
@settings(max_examples=300, deadline=None)
def test_gains_off_the_relation_beyond_their_rounding_are_not_detected(ku, tu_s, off, sign):
    """Kd moved by a share of itself that the three decimals of all three gains cannot explain."""
    kp, ki, kd = (float(g) for g in saved(ku, tu_s))
    rounding = 0.0005 / ki + 0.0005 / kd + 2.0 * 0.0005 / kp  # Kd Ki against Kp^2 / 4, relative, first order
    factor = 1.0 + sign * max(off, 3.0 * rounding)
    assert detect(f"{kp:.3f}", f"{ki:.3f}", f"{kd * factor:.3f}") is None


def test_gains_whose_rounding_could_make_them_zero_are_no_relay():
    assert detect("10.0", "0.0", "25.0") is None
    assert detect("0.0004", "0.0004", "0.0004") is None


def test_example_config_gains_are_no_evidence_of_this_heater():
    assert example_gains("22.2", "1.08", "114") and example_gains("54.027", "0.77", "948.182")
    assert not example_gains("24.831", "1.346", "114.532")
    found, why = from_config({"control": "pid", "pid_kp": "22.2", "pid_ki": "1.08", "pid_kd": "114"})
    assert found is None and "example-config" in why


def test_a_klippy_config_section_says_what_it_holds():
    found, why = from_config({"control": "pid", "pid_kp": "24.831", "pid_ki": "1.346", "pid_kd": "114.532"})
    assert found is not None and found.tu_s == pytest.approx(36.9, abs=0.05) and "PID_CALIBRATE's" in why
    found, why = from_config({"control": "pid", "pid_kp": "40.68", "pid_ki": "7.93", "pid_kd": "139.15"})
    assert found is None and "not PID_CALIBRATE's" in why and "1103.5" in why
    assert from_config({"control": "watermark"}) == (None, "no PID gains saved")


@pytest.mark.parametrize(("name", "heater", "tu_s"), [
    ("klippy_stats_chesleavens_cartesian_stm32f103.csv", "extruder", 17.4),
    ("klippy_stats_icodextrin_ender5_creality427.csv", "extruder", 36.9),
    ("klippy_stats_ianryeng_corexy_ebbcan.csv", "extruder", 5.4),
    ("klippy_stats_jakew02_redoubt_longprint.csv", "heater_bed", 49.8),
    ("klippy_stats_chesleavens_cartesian_stm32f103.csv", "heater_bed", None),  # example-config gains
    ("klippy_stats_shreypatel_cartesian_stm32f407.csv", "extruder", None),  # example-config gains
    ("klippy_stats_pdegrazia_kingroon_kp3s_a.csv", "heater_bed", None),  # hand-set, off the relation
])
def test_the_klippy_logs_saved_gains(hardware_logs, name, heater, tu_s):
    """README E's derived Tu, to its printed decimal; docs/validation.md section 3's Tu saved column."""
    from tools.logs import load_log

    found, _ = from_config(load_log(hardware_logs / name).meta["config"][heater])
    assert (found is None) == (tu_s is None)
    if found is not None:
        assert found.tu_s == pytest.approx(tu_s, abs=0.05)
