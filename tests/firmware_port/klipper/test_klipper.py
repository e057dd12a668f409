"""Klipper's host-side heater: ControlPID step by step, set_pwm suppression (all version options),
the EMA, the watermark, PID_CALIBRATE on a small plant and against saved real calibrations,
verify_heater, and the Stats fragment."""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from decimal import Decimal
from itertools import product
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.klipper import (
    CommandError,
    HeaterConfig,
    HeaterFault,
    KlipperHeater,
    PidCalibrate,
    PwmEvent,
    VerifyHeater,
    invert_calibration,
    relay_ku,
    zn_from_relay,
)
from firmware_port.klipper.heater import (
    AMBIENT_TEMP,
    MAX_HEAT_TIME,
    MIN_PWM_CHANGE_2026_03,
    MIN_PWM_CHANGE_BEFORE_2026_03,
    PWM_GUARD_2024_03,
    PWM_GUARD_2024_12,
    PWM_GUARD_BEFORE_2024_03,
    PWM_RESEND_2025_04,
    PWM_RESEND_2025_08,
    PWM_RESEND_BEFORE_2025_04,
    QUELL_STALE_2025_07,
    QUELL_STALE_BEFORE_2025_07,
    REPORT_TIME,
    SAMPLE_COUNT,
    SAMPLE_TIME,
)
from firmware_port.klipper.pid_calibrate import ControlAutoTune

COLLECTION = "klipper_pid_calibrate_results_collection.txt"  # in the hardware logs


def make_heater(name: str = "extruder", **options) -> KlipperHeater:
    """A PID heater (Klipper's example extruder gains unless given), min 0 / max 300 degC."""
    options = {"pid_kp": 22.2, "pid_ki": 1.08, "pid_kd": 114.0, **options}
    return KlipperHeater(HeaterConfig(name, 0.0, 300.0, **options))


def powered(heater: KlipperHeater, target_c: float) -> KlipperHeater:
    """Set a target and feed the main-thread watchdog far ahead (no stats() calls needed)."""
    heater.set_target(target_c)
    heater.stats(1e6)
    return heater


# --- ControlPID, step by step ------------------------------------------------------------------


def test_pid_first_update_and_both_derivative_branches():
    # Kp = 25.5/255 = 0.1, Ki = 0.01, Kd = 0.2; smooth_time 1 s
    heater = powered(make_heater(pid_kp=25.5, pid_ki=2.55, pid_kd=51.0), 30.0)
    pid = heater.control
    assert (pid.prev_temp, pid.prev_temp_time) == (AMBIENT_TEMP, 0.0)
    # First update: dt = read_time - 0 = 2 s >= smooth_time -> deriv = (27 - 25)/2 = 1.0;
    # err 3, integ 3*2 = 6; co = 0.3 + 0.06 - 0.2 = 0.16
    event = heater.temperature_callback(2.0, 27.0)
    assert event == PwmEvent(pytest.approx(2.3), pytest.approx(0.16))
    assert (pid.prev_temp_deriv, pid.prev_temp_integ) == (pytest.approx(1.0), pytest.approx(6.0))
    # dt 0.3 < smooth_time: deriv = (1.0*(1 - 0.3) + 0.6)/1 = 1.3; err 2.4, integ 6.72;
    # co = 0.24 + 0.0672 - 0.26 = 0.0472
    event = heater.temperature_callback(2.3, 27.6)
    assert event == PwmEvent(pytest.approx(2.6), pytest.approx(0.0472))
    assert (pid.prev_temp_deriv, pid.prev_temp_integ) == (pytest.approx(1.3), pytest.approx(6.72))


@pytest.mark.parametrize(
    ("smooth_time_s", "deriv"),
    [(1.0, 3.0 / 1.5), (2.0, (0.5 * 0.5 + 3.0) / 2.0)],  # direct slope / filtered (prev deriv 0.5)
)
def test_pid_min_deriv_time_is_smooth_time(smooth_time_s, deriv):
    heater = powered(make_heater(smooth_time_s=smooth_time_s), 100.0)
    pid = heater.control
    pid.prev_temp, pid.prev_temp_time, pid.prev_temp_deriv = 50.0, 10.0, 0.5
    heater.temperature_callback(11.5, 53.0)
    assert pid.prev_temp_deriv == pytest.approx(deriv)


def test_pid_conditional_integration_when_clipped():
    # Kp 1, Ki 0.01, Kd 0, max_power 0.5 (integ clamp 50)
    heater = powered(make_heater(pid_kp=255.0, pid_ki=2.55, pid_kd=0.0, max_power=0.5), 200.0)
    pid = heater.control
    # err 175 over dt 1 s: integ 175 -> clamp 50; co = 175 + 0.5, clipped to 0.5: integ not kept
    assert heater.temperature_callback(1.0, 25.0) == PwmEvent(pytest.approx(1.3), 0.5)
    assert pid.prev_temp_integ == 0.0
    # err 0.2: integ 0.06, co = 0.2 + 0.0006 not clipped: kept
    assert heater.temperature_callback(1.3, 199.8) == PwmEvent(pytest.approx(1.6), pytest.approx(0.2006))
    assert pid.prev_temp_integ == pytest.approx(0.06)
    # err -1: integ -0.24 -> clamp 0; co = -1, clipped to 0: integ not kept
    assert heater.temperature_callback(1.6, 201.0) == PwmEvent(pytest.approx(1.9), 0.0)
    assert pid.prev_temp_integ == pytest.approx(0.06)


def test_pid_integral_clamp_at_max_power_over_ki():
    # Kp 0, Ki 0.01, Kd 0, max_power 0.5: temp_integ_max = 50 and co = Ki*integ <= max_power
    heater = powered(make_heater(pid_kp=0.0, pid_ki=2.55, pid_kd=0.0, max_power=0.5), 100.0)
    pid = heater.control
    assert pid.temp_integ_max == pytest.approx(50.0)
    assert heater.temperature_callback(100.0, 90.0).value == pytest.approx(0.5)  # integ 1000 -> 50
    assert pid.prev_temp_integ == pytest.approx(50.0)
    heater.temperature_callback(100.3, 90.0)  # 53 -> 50
    assert pid.prev_temp_integ == pytest.approx(50.0)
    assert heater.temperature_callback(100.6, 110.0).value == pytest.approx(0.47)  # unwinds from 50
    assert pid.prev_temp_integ == pytest.approx(47.0)


def test_pid_without_ki_has_no_integral():
    heater = powered(make_heater(pid_ki=0.0), 200.0)
    heater.temperature_callback(1.0, 100.0)
    assert heater.control.temp_integ_max == 0.0 and heater.control.prev_temp_integ == 0.0


def test_pid_check_busy_on_smoothed_temp_and_slope():
    heater = powered(make_heater(), 200.0)
    for step in range(100):
        heater.temperature_callback(1.0 + REPORT_TIME * step, 199.5)
    assert not heater.check_busy(0.0)  # |200 - 199.5| <= 1 and slope 0
    heater.temperature_callback(1.0 + REPORT_TIME * 100, 199.7)  # slope (0.2)/1 = 0.2 > 0.1
    assert heater.check_busy(0.0)


@given(
    temps=st.lists(st.floats(0.0, 400.0), min_size=1, max_size=60),
    gains=st.tuples(st.floats(0.0, 100.0), st.floats(0.0, 10.0), st.floats(0.0, 500.0)),
    max_power=st.floats(0.05, 1.0),
)
def test_pid_output_and_integral_stay_in_range(temps, gains, max_power):
    kp, ki, kd = gains
    heater = powered(make_heater(pid_kp=kp, pid_ki=ki, pid_kd=kd, max_power=max_power), 210.0)
    for step, temp in enumerate(temps):
        event = heater.temperature_callback(1.0 + REPORT_TIME * step, temp)
        assert event is None or 0.0 <= event.value <= max_power
        assert 0.0 <= heater.control.prev_temp_integ <= heater.control.temp_integ_max


# --- set_pwm: forced zero, suppression, resend ------------------------------------------------


def test_pwm_forced_to_zero_without_target_or_watchdog():
    heater = make_heater()
    heater.set_target(200.0)  # no stats() yet: the main-thread watchdog forces 0
    assert heater.set_pwm(1.0, 1.0) is None
    heater.stats(0.0)  # watchdog fed until 5.0
    assert heater.set_pwm(1.0, 1.0) == PwmEvent(1.3, 1.0)
    assert heater.set_pwm(5.1, 1.0) == PwmEvent(pytest.approx(5.4), 0.0)  # watchdog expired
    heater.stats(5.1)
    heater.set_target(0.0)
    assert heater.set_pwm(5.4, 1.0) is None  # forced 0, same as the last sent value
    heater.handle_shutdown()
    heater.stats(6.0)  # no longer feeds the watchdog
    assert heater.verify_mainthread_time == -999.0


@pytest.mark.parametrize(("guard", "without_stats", "after_shutdown"), [
    (PWM_GUARD_2024_12, None, None), (PWM_GUARD_2024_03, PwmEvent(1.3, 1.0), PwmEvent(pytest.approx(2.3), 0.0)),
    (PWM_GUARD_BEFORE_2024_03, PwmEvent(1.3, 1.0), PwmEvent(pytest.approx(2.3), 0.5))])
def test_pwm_guard_versions(guard, without_stats, after_shutdown):
    """2024-12: the watchdog (no stats(), no heat); 2024-03: only a shutdown forces 0; before: nothing does."""
    heater = make_heater(pwm_guard=guard)
    heater.set_target(200.0)
    assert heater.set_pwm(1.0, 1.0) == without_stats
    heater.stats(1.0)
    heater.handle_shutdown()
    assert heater.set_pwm(2.0, 0.5) == after_shutdown


@pytest.mark.parametrize(("quell", "reads_c"), [(QUELL_STALE_2025_07, 150.0), (QUELL_STALE_BEFORE_2025_07, 0.0)])
def test_stale_sensor_quell_versions(quell, reads_c):
    """A last reading at 10.0 s: at 15.1 s Klipper 0.12 (5 s) reads 0, mainline since 2025-07 (7 s) still 150."""
    heater = make_heater(quell_stale=quell, smooth_time_s=0.01)
    heater.temperature_callback(10.0, 150.0)
    assert heater.get_temp(15.1) == (reads_c, 0.0)
    assert heater.get_temp(17.1)[0] == 0.0


def test_version_switches_are_checked():
    with pytest.raises(ValueError, match="quell_stale must be one of"):
        make_heater(quell_stale="2030")
    with pytest.raises(ValueError, match="pwm_guard must be one of"):
        make_heater(pwm_guard="2030")


@pytest.mark.parametrize(
    ("rule", "max_power", "value", "sent"),
    [
        (MIN_PWM_CHANGE_2026_03, 1.0, 0.049, False),
        (MIN_PWM_CHANGE_2026_03, 1.0, 0.05, True),
        (MIN_PWM_CHANGE_2026_03, 0.5, 0.024, False),
        (MIN_PWM_CHANGE_2026_03, 0.5, 0.025, True),
        (MIN_PWM_CHANGE_BEFORE_2026_03, 0.5, 0.049, False),
        (MIN_PWM_CHANGE_BEFORE_2026_03, 0.5, 0.05, True),
    ],
)
def test_small_request_from_zero_is_never_sent(rule, max_power, value, sent):
    heater = powered(make_heater(max_power=max_power, min_pwm_change=rule), 200.0)
    events = [heater.set_pwm(step * REPORT_TIME, value) for step in range(100)]  # 30 s
    assert any(events) == sent
    assert heater.last_pwm_value == (value if sent else 0.0)


def test_watermark_with_small_max_power_never_heats_before_2026_03():
    """The bug fixed by 01f089e71: max_power below 0.05 could never be sent."""
    for rule, heats in ((MIN_PWM_CHANGE_BEFORE_2026_03, False), (MIN_PWM_CHANGE_2026_03, True)):
        heater = powered(make_heater(control="watermark", max_power=0.04, min_pwm_change=rule), 200.0)
        assert (heater.temperature_callback(1.0, 25.0) is not None) == heats


@pytest.mark.parametrize(
    ("rule", "resend_after_reports"),
    # next_pwm_time - read_time: 0.3 + 2.099 = 2.399 s; 0.3 + 0.75*3 = 2.55 s; 0.3 + 0.75*5 = 4.05 s
    [(PWM_RESEND_2025_08, 8), (PWM_RESEND_2025_04, 9), (PWM_RESEND_BEFORE_2025_04, 14)],
)
def test_small_changes_are_held_until_the_resend_time(rule, resend_after_reports):
    heater = powered(make_heater(pwm_resend=rule), 200.0)
    assert heater.set_pwm(0.0, 0.5) == PwmEvent(0.3, 0.5)
    held = [heater.set_pwm(step * REPORT_TIME, 0.52) for step in range(1, resend_after_reports)]
    assert held == [None] * (resend_after_reports - 1) and heater.last_pwm_value == 0.5
    event = heater.set_pwm(resend_after_reports * REPORT_TIME, 0.52)
    assert event == PwmEvent(pytest.approx((resend_after_reports + 1) * REPORT_TIME), 0.52)
    assert heater.set_pwm((resend_after_reports + 1) * REPORT_TIME, 0.6) is not None  # a big change goes at once


@given(
    requests=st.lists(st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.5, 0.52, 0.54])), min_size=2, max_size=80),
    rule=st.sampled_from([PWM_RESEND_2025_08, PWM_RESEND_2025_04, PWM_RESEND_BEFORE_2025_04]),
)
def test_a_nonzero_pwm_is_refreshed_within_max_heat_time(requests, rule):
    """The MCU shuts down if a heater stays on MAX_HEAT_TIME without a new event: the resend
    window must always beat it with 0.3 s reports."""
    heater = powered(make_heater(pwm_resend=rule), 200.0)
    events = [heater.set_pwm(step * REPORT_TIME, value) for step, value in enumerate(requests)]
    sent = [event for event in events if event is not None]
    # the run ends with the last report: an event due by then must have been sent
    end = PwmEvent(len(requests) * REPORT_TIME, 0.0)
    for event, following in zip(sent, [*sent[1:], end]):
        if event.value:
            assert following.time_s - event.time_s < MAX_HEAT_TIME[rule]


# --- smoothing and watermark -------------------------------------------------------------------


@pytest.mark.parametrize("smooth_time_s", [1.0, 2.0])
def test_smoothed_temp_is_an_ema(smooth_time_s):
    heater = powered(make_heater(smooth_time_s=smooth_time_s), 200.0)
    heater.temperature_callback(100.0, 30.0)  # dt 100 s >= smooth_time: adj 1, smoothed = temp
    assert heater.smoothed_temp == 30.0
    alpha = REPORT_TIME / smooth_time_s
    for step in range(1, 11):
        heater.temperature_callback(100.0 + step * REPORT_TIME, 40.0)
        assert heater.smoothed_temp == pytest.approx(40.0 - 10.0 * (1.0 - alpha) ** step)
    assert heater.last_temp == 40.0


def test_watermark_hysteresis():
    heater = powered(make_heater(control="watermark", max_power=0.8), 200.0)
    temps = [190.0, 201.0, 202.0, 199.0, 198.1, 198.0, 201.9, 202.0]
    sent = [heater.temperature_callback(1.0 + step * REPORT_TIME, temp) for step, temp in enumerate(temps)]
    assert [event and event.value for event in sent] == [0.8, None, 0.0, None, None, 0.8, None, 0.0]
    assert heater.check_busy(0.0) == (heater.smoothed_temp < 198.0)


# --- PID_CALIBRATE ---------------------------------------------------------------------------


@dataclass
class Plant:
    """First order plus dead time: tau dT/dt = gain * pwm(t - dead_time) - (T - ambient)."""

    gain_c: float = 250.0
    tau_s: float = 60.0
    dead_time_s: float = 2.0
    temp_c: float = AMBIENT_TEMP


TICK_S = 0.05
TICKS_PER_REPORT = 6  # 0.3 s
TICKS_PER_SECOND = 20


def run(heater: KlipperHeater, plant: Plant, duration_s: float, every_second=None, start_s: float = 100.0) -> float:
    """Drive the heater as the twin would: a report every 0.3 s (read_time = sample + 8 ms), each
    sent PWM applied at its time (plus the plant's dead time), stats() and ``every_second(t)``
    once a second; stops early when that returns True. Returns the end time."""
    pending: list[PwmEvent] = []
    pwm = 0.0
    decay = math.exp(-TICK_S / plant.tau_s)
    for tick in range(round(duration_s / TICK_S)):
        now = start_s + tick * TICK_S
        while pending and pending[0].time_s + plant.dead_time_s <= now:
            pwm = pending.pop(0).value
        if tick % TICKS_PER_SECOND == 0:
            heater.stats(now)
        if tick % TICKS_PER_REPORT == 0:
            event = heater.temperature_callback(now + SAMPLE_COUNT * SAMPLE_TIME, plant.temp_c)
            if event is not None:
                pending.append(event)
        if tick % TICKS_PER_SECOND == 0 and every_second is not None and every_second(now):
            return now
        steady = AMBIENT_TEMP + plant.gain_c * pwm
        plant.temp_c = steady + (plant.temp_c - steady) * decay
    return start_s + duration_s


REPLY_RE = re.compile(r"PID parameters: pid_Kp=(\d+\.\d{3}) pid_Ki=(\d+\.\d{3}) pid_Kd=(\d+\.\d{3})")
F = r"-?\d+\.\d{6}"
RAW_RE = re.compile(rf"Autotune: raw={F}/{F} Ku={F} Tu={F}  Kp={F} Ki={F} Kd={F}")
FINAL_RE = re.compile(rf"Autotune: final: Kp={F} Ki={F} Kd={F}")


def test_pid_calibrate_on_a_plant(caplog):
    heater = make_heater()
    calibrate = PidCalibrate(heater, 200.0)
    tune = calibrate.tune
    caplog.set_level(logging.INFO, logger="firmware_port.klipper")
    end_s = run(heater, Plant(), 600.0, every_second=lambda now: not calibrate.check_busy(now))
    assert end_s < 600.0, "PID_CALIBRATE did not finish"
    reply = calibrate.finish()

    # 12 peaks, the heater off, the control restored with target 0
    assert len(tune.peaks) == 12 and not tune.heating
    assert tune.peaks[0] == (0.0, 0.0)
    assert heater.last_pwm_value == 0.0 and heater.target_temp == 0.0
    assert heater.control is calibrate.old_control
    # the relay swings between target - 5 and target plus overshoot, not around the target
    maxima, minima = [p[0] for p in tune.peaks[2::2]], [p[0] for p in tune.peaks[3::2]]
    assert min(maxima) > 200.0 and max(minima) < 195.0 and max(maxima) < 205.0

    # the median rule, computed independently
    cycles = sorted((tune.peaks[pos][1] - tune.peaks[pos - 2][1], pos) for pos in range(4, 12))
    pos = cycles[4][1]
    swing_c = tune.peaks[pos][0] - tune.peaks[pos - 1][0]
    ku = 4.0 / (math.pi * abs(swing_c) / 2.0)
    kp = 0.6 * ku * 255.0
    tu_s = cycles[4][0]
    expected = (kp, kp / (tu_s / 2.0), kp * tu_s / 8.0)

    assert reply == [
        "PID parameters: pid_Kp={:.3f} pid_Ki={:.3f} pid_Kd={:.3f}".format(*expected),
        "The SAVE_CONFIG command will update the printer config file",
        "with these parameters and restart the printer.",
    ]
    assert REPLY_RE.fullmatch(reply[0])
    assert calibrate.saved_options == {
        "control": "pid",
        "pid_Kp": f"{expected[0]:.3f}",
        "pid_Ki": f"{expected[1]:.3f}",
        "pid_Kd": f"{expected[2]:.3f}",
    }
    # one raw line per switch from the 4th peak on, one for the final pick, then the final line
    messages = [record.getMessage() for record in caplog.records if record.getMessage().startswith("Autotune")]
    assert len(messages) == (12 - 3) + 1 + 1
    assert all(RAW_RE.fullmatch(line) for line in messages[:-1]), messages
    assert FINAL_RE.fullmatch(messages[-1])
    assert messages[-1] == "Autotune: final: Kp={:f} Ki={:f} Kd={:f}".format(*expected)
    raw = (swing_c, ku, tu_s, *expected)
    assert messages[-2] == "Autotune: raw={:f}/1.000000 Ku={:f} Tu={:f}  Kp={:f} Ki={:f} Kd={:f}".format(*raw)

    # WRITE_FILE=1's format: requested pwm changes at read_time + pwm_delay, then the samples
    lines = tune.heattest_text().splitlines()
    assert lines[0].startswith("pwm: ") and re.fullmatch(r"pwm: \d+\.\d{3} 1\.000", lines[0])
    assert re.fullmatch(r"\d+\.\d{3} \d+\.\d{3}", lines[-1])


def test_calc_final_pid_takes_the_upper_median_cycle():
    tune = ControlAutoTune(make_heater(), 200.0)
    times = [0, 0.3, 80, 90, 100, 110, 121, 130, 139, 151, 160, 171]
    temps = [0, 25, 210, 194, 208, 195, 207, 194, 209, 195, 208, 194]
    tune.peaks = list(zip(temps, times))
    # cycles (pos 4..11): 20 20 21 20 18 21 21 20 -> sorted, index 4 of 8 is (20, pos 11)
    assert tune.calc_final_pid() == tune.calc_pid(11)
    kp = 0.6 * 255.0 * 4.0 / (math.pi * 7.0)  # swing 194 - 208: a = 7
    assert tune.calc_pid(11) == pytest.approx((kp, kp / 10.0, kp * 2.5))


def test_pid_calibrate_interrupted_and_out_of_range():
    heater = make_heater()
    calibrate = PidCalibrate(heater, 200.0)
    run(heater, Plant(), 30.0)
    with pytest.raises(CommandError, match="^pid_calibrate interrupted$"):
        calibrate.finish()
    assert heater.control is calibrate.old_control and heater.target_temp == 0.0
    with pytest.raises(CommandError, match=re.escape("Requested temperature (350.0) out of range (0.0:300.0)")):
        PidCalibrate(heater, 350.0)
    assert heater.control is calibrate.old_control


# --- the formulas against saved real calibrations ----------------------------------------------


@dataclass(frozen=True)
class Saved:
    """A saved calibration and the derived columns the collection prints for it."""

    source: str
    gains: tuple[str, str, str]  # Kp, Ki, Kd as printed
    tu: tuple[str, str]  # Tu from 2Kp/Ki and from 8Kd/Kp
    peak_to_peak: str | None
    max_power: float
    consistent: bool  # the file says the two Tu agree


GAIN_RE = re.compile(r"(?:pid_)?K([pid])\s*[=:]\s*(\d+\.\d+)", re.IGNORECASE)
DERIVED_RE = re.compile(r"derived.*?: Tu=(\d+\.\d+) s, (\d+\.\d+) s(?:, p-p (\d+\.\d+) C)?")
TABLE_RE = re.compile(
    r"(\w+) pid_kp = (\S+) pid_ki = (\S+) pid_kd = (\S+)\s+-> Tu (\S+)/(\S+) s, p-p (\S+) C(?: at max_power (\S+))?"
)
SHORT_RE = re.compile(
    r"(\w+) ([\d.]+)/([\d.]+)/([\d.]+) \((?:rounded; consistent with Z-N, |(inconsistent): )"
    r"Tu ([\d.]+)(?:/| vs )([\d.]+) s(?:, p-p ([\d.]+) C)?"
)


@pytest.fixture(scope="module")
def collection(hardware_logs: Path) -> list[Saved]:
    """The calibrations of klipper_pid_calibrate_results_collection.txt that carry derived Tu columns."""
    saved, pending, source = [], {}, ""
    for line in (hardware_logs / COLLECTION).read_text().splitlines():
        words = line[1:].split()
        if line.startswith("# [") or (words and words[0].endswith(".csv")):
            source, pending = words[0], {}  # "[3]" or the capture file of a table row
        if not line.startswith("#"):  # value lines: "Kp=..", "pid_Kp=..", "pid_kp = ..", "pid_Kp: .."
            for key, value in GAIN_RE.findall(line):
                if key.lower() in pending:
                    pending = {}
                pending[key.lower()] = value
        elif match := DERIVED_RE.search(line):
            gains = (pending["p"], pending["i"], pending["d"])
            saved.append(Saved(source, gains, match.group(1, 2), match[3], 1.0, "do not agree" not in line))
            pending = {}
        elif match := TABLE_RE.search(line):
            max_power = float(match[8] or 1.0)
            saved.append(
                Saved(f"{source} {match[1]}", match.group(2, 3, 4), match.group(5, 6), match[7], max_power, True)
            )
        else:
            for match in SHORT_RE.finditer(line):
                saved.append(
                    Saved(f"{source} {match[1]}", match.group(2, 3, 4), match.group(6, 7), match[8], 1.0, not match[5])
                )
    return saved


def half_unit(printed: str) -> float:
    """Half the last printed digit: how far the true value can be from a rounded one."""
    return float(Decimal(1).scaleb(Decimal(printed).as_tuple().exponent)) / 2.0


def test_collection_is_read_completely(collection):
    saved = collection
    assert len(saved) >= 19, [s.source for s in saved]
    assert sum(not s.consistent for s in saved) >= 2
    assert sum(s.max_power != 1.0 for s in saved) >= 2


def test_inversion_reproduces_the_derived_columns(collection):
    for s in collection:
        tu_ki, tu_kd, _, peak_to_peak = invert_calibration(*map(float, s.gains), s.max_power)
        assert abs(tu_ki - float(s.tu[0])) <= half_unit(s.tu[0]) + 1e-9, s
        assert abs(tu_kd - float(s.tu[1])) <= half_unit(s.tu[1]) + 1e-9, s
        if s.peak_to_peak is not None:
            assert abs(peak_to_peak - float(s.peak_to_peak)) <= half_unit(s.peak_to_peak) + 1e-9, s


def test_zn_reproduces_every_saved_calibration_from_its_ku_and_tu(collection):
    """Klipper's rule on the printed Tu and Ku (from the printed swing and max_power), over the
    rounding of the printed numbers, contains the saved gains to their own rounding."""
    for s in collection:
        tu_ki, tu_kd, _, _ = invert_calibration(*map(float, s.gains), s.max_power)
        if not s.consistent:
            assert abs(tu_ki - tu_kd) > 0.1 * tu_ki, f"{s.source}: marked inconsistent but the two Tu agree"
            continue
        tus = [float(t) + sign * half_unit(t) for t in s.tu for sign in (-1, 1)]
        swings = [float(s.peak_to_peak) + sign * half_unit(s.peak_to_peak) for sign in (-1, 1)]
        corners = [zn_from_relay(relay_ku(swing, s.max_power), tu) for swing, tu in product(swings, tus)]
        for index, printed in enumerate(s.gains):
            low = min(c[index] for c in corners) - half_unit(printed)
            high = max(c[index] for c in corners) + half_unit(printed)
            assert low <= float(printed) <= high, f"{s.source}: gain {'pid'[index]} {printed} not in [{low}, {high}]"


def test_inverting_the_chesleavens_extruder_calibration():
    tu_ki, tu_kd, ku, peak_to_peak = invert_calibration(29.229, 3.360, 63.573)
    assert (round(tu_ki, 2), round(tu_kd, 2), round(peak_to_peak, 1)) == (17.40, 17.40, 13.3)
    assert ku == pytest.approx(29.229 / 153.0)


@given(ku=st.floats(0.01, 10.0), tu_s=st.floats(0.5, 500.0), max_power=st.floats(0.05, 1.0))
def test_invert_calibration_undoes_zn_from_relay(ku, tu_s, max_power):
    swing = 8.0 * max_power / (math.pi * ku)
    assert relay_ku(swing, max_power) == pytest.approx(ku)
    tu_ki, tu_kd, ku_back, swing_back = invert_calibration(*zn_from_relay(ku, tu_s), max_power)
    assert (tu_ki, tu_kd, ku_back, swing_back) == pytest.approx((tu_s, tu_s, ku, swing))


# --- verify_heater ----------------------------------------------------------------------------


def verify_run(heater: KlipperHeater, plant: Plant, target_c: float, duration_s: float):
    """Heat to target under verify_heater; returns (fault time or None, the fault)."""
    verify = VerifyHeater(heater)
    heater.set_target(target_c)
    fault: list = []

    def check(now: float) -> bool:
        try:
            verify.check_event(now)
        except HeaterFault as error:
            fault.append(error)
            return True
        return False

    end_s = run(heater, plant, duration_s, every_second=check)
    return (end_s, fault[0]) if fault else (None, None)


@pytest.mark.parametrize(
    ("name", "fault_s"),
    [("extruder", 21.0), ("heater_bed", 61.0)],  # check_gain_time 20 / 60 s, then error >= 120 at once
)
def test_verify_heater_trips_on_a_heater_that_does_not_heat(name, fault_s, caplog):
    caplog.set_level(logging.INFO, logger="firmware_port.klipper")
    heater = make_heater(name)
    when, fault = verify_run(heater, Plant(gain_c=0.0), 200.0 if name == "extruder" else 60.0, 300.0)
    assert when == pytest.approx(100.0 + fault_s)
    assert str(fault) == (
        f"Heater {name} not heating at expected rate\n"
        "See the 'verify_heater' section in docs/Config_Reference.md\n"
        "for the parameters that control this check.\n"
    )
    target = "200.000" if name == "extruder" else "60.000"
    assert [record.getMessage() for record in caplog.records] == [
        f"Starting heater checks for {name}",
        f"Heater {name} approaching new target of {target}",
        f"Heater {name} no longer approaching target {target}",
        f"Heater {name} not heating at expected rate",
    ]
    assert caplog.records[-1].levelno == logging.ERROR


def test_verify_heater_trips_on_a_heater_too_weak_to_gain_2c_in_20s():
    when, fault = verify_run(make_heater(), Plant(gain_c=40.0, tau_s=600.0), 200.0, 300.0)
    assert fault is not None and when < 130.0


def test_verify_heater_passes_a_normal_heat_up(caplog):
    caplog.set_level(logging.INFO, logger="firmware_port.klipper")
    heater = make_heater()
    _, fault = verify_run(heater, Plant(), 200.0, 400.0)
    assert fault is None
    assert abs(heater.smoothed_temp - 200.0) < 1.0
    assert "Heater extruder within range of 200.000" in [record.getMessage() for record in caplog.records]


# --- Stats --------------------------------------------------------------------------------------


def test_stats_fragment_shows_raw_temp_and_last_sent_pwm():
    heater = make_heater(pid_kp=0.0, pid_ki=0.0, pid_kd=0.0)
    assert heater.stats(0.0) == (False, "extruder: target=0 temp=0.0 pwm=0.000")
    heater.set_target(210.0)
    heater.last_temp, heater.smoothed_temp, heater.last_pwm_value = 209.34, 205.0, 0.64
    assert heater.stats(1.0) == (True, "extruder: target=210 temp=209.3 pwm=0.640")
    bed = make_heater("heater_bed")
    bed.set_target(60.0)
    bed.last_temp = 59.2
    assert bed.stats(1.0) == (True, "heater_bed: target=60 temp=59.2 pwm=0.000")
    chamber = make_heater("heater_generic chamber")
    chamber.last_temp = 49.96
    assert chamber.stats(1.0) == (False, "chamber: target=0 temp=50.0 pwm=0.000")  # active above 50
    chamber.last_temp = 50.04
    assert chamber.stats(1.0) == (True, "chamber: target=0 temp=50.0 pwm=0.000")


def test_stats_pwm_is_the_sent_value_not_the_pid_output():
    heater = powered(make_heater(pid_kp=25.5, pid_ki=0.0, pid_kd=0.0), 200.0)  # co = 0.1 * err
    heater.temperature_callback(10.0, 195.0)  # co 0.5, sent
    heater.temperature_callback(10.3, 195.3)  # co 0.47, held
    assert heater.stats(10.3)[1] == "extruder: target=200 temp=195.3 pwm=0.500"
