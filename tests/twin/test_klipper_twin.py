"""The Klipper twin: heat-up with Klipper's default PID, Stats lines as klippy.log writes them (raw
last temp, last *sent* pwm), the 0.3 s actuation delay through the MCU's soft PWM, verify_heater and
the ADC range check halting everything, PID_CALIBRATE, ADC resolution, determinism."""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest

from firmware_port.klipper import CommandError, ControlPID
from firmware_port.klipper.heater import REPORT_TIME, SAMPLE_COUNT, SAMPLE_TIME
from tools.logs import parse_klippy_log
from twin.engine import DISCONNECTED, STUCK_ON
from twin.klipper_twin import (
    ADC_FIRST_SAMPLE_S,
    ATMEGA2560,
    KlipperTwin,
    SoftPwm,
    bed_setup,
    extruder_setup,
)
from twin.linear import TICK_S
from twin.plants import make_plant

TARGET_C = 200.0
BED_C = 60.0


class RecordingPlant:
    """A plant that keeps every heater input it is advanced with (one entry per tick)."""

    def __init__(self, plant):
        self.plant = plant
        self.runs: list[np.ndarray] = []

    def advance(self, u):
        self.runs.append(np.array(u, dtype=float))
        self.plant.advance(u)

    def __getattr__(self, name):
        return getattr(self.plant, name)

    @property
    def u(self) -> np.ndarray:
        return np.concatenate(self.runs)


def heat_up(seconds: float = 600.0, bed: bool = True, extruder_plant=None, bed_plant=None) -> KlipperTwin:
    """Extruder to 200 C (and the bed to 60 C) from time 0."""
    heaters = [extruder_setup(extruder_plant)] + ([bed_setup(bed_plant)] if bed else [])
    twin = KlipperTwin(heaters)
    twin.set_target("extruder", TARGET_C, at_s=0.0)
    if bed:
        twin.set_target("heater_bed", BED_C, at_s=0.0)
    twin.run_until(seconds)
    return twin


@pytest.fixture(scope="module")
def heated() -> KlipperTwin:
    return heat_up()


def test_default_pid_heats_the_default_hotend_and_holds(heated):
    t_s, temp_c = heated.column("extruder", "t_s"), heated.column("extruder", "temp_c")
    assert not heated.halted
    reached_s = t_s[np.argmax(temp_c >= TARGET_C - 1.0)]
    print(f"\nreached {TARGET_C - 1:.0f} C at {reached_s:.1f} s, peak {temp_c.max():.2f} C")
    assert reached_s < 150.0
    assert temp_c.max() < TARGET_C + 5.0
    held = temp_c[t_s > 300.0]
    assert np.all(np.abs(held - TARGET_C) < 1.0)
    assert np.all(np.abs(heated.column("extruder", "sensor_c")[t_s > 300.0] - TARGET_C) < 1.0)
    assert "Heater extruder within range of 200.000" in heated.klippy_log()


def test_reports_every_0_3_s_at_sample_time_plus_8_ms(heated):
    t_s = heated.column("extruder", "t_s")
    assert t_s[0] == pytest.approx(ADC_FIRST_SAMPLE_S + SAMPLE_COUNT * SAMPLE_TIME)
    assert np.allclose(np.diff(t_s), REPORT_TIME)
    assert heated.column("heater_bed", "t_s")[0] > t_s[0]  # the next query slot


def test_stats_lines_parse_and_show_raw_temp_and_last_sent_pwm(heated, tmp_path):
    path = tmp_path / "klippy.log"
    path.write_text(heated.klippy_log())
    (session,) = parse_klippy_log(path).sessions
    assert set(session) == {"extruder", "heater_bed"}
    line = heated.stats_lines[100]
    assert re.fullmatch(r"Stats 100\.0: extruder: target=200 temp=\d+\.\d pwm=\d\.\d{3} "
                        r"heater_bed: target=60 temp=\d+\.\d pwm=\d\.\d{3} "
                        r"print_time=100\.000 buffer_time=0\.000 print_stall=0", line), line
    for name in ("extruder", "heater_bed"):
        series = session[name]
        reports = heated.reports(name)
        report_t = np.array([row.t_s for row in reports])
        sends = heated.sends(name)
        send_t = np.array([read for read, _, _ in sends])
        for t_s, temp_c, pwm in zip(series.t_s, series.temp_c, series.pwm):
            i = np.searchsorted(report_t, t_s, side="right") - 1
            last_temp = reports[i].temp_c if i >= 0 else 0.0
            assert temp_c == float(f"{last_temp:.1f}")  # the raw last report, not the smoothed one
            j = np.searchsorted(send_t, t_s, side="right") - 1
            assert pwm == float(f"{sends[j][2] if j >= 0 else 0.0:.3f}")  # the last value sent
    # temp is the raw report: during the heat-up it differs from the smoothed temperature
    smoothed = heated.column("extruder", "smoothed_c")
    assert np.max(np.abs(heated.column("extruder", "temp_c") - smoothed)) > 1.0


def test_pwm_changes_only_by_5_percent_or_at_the_resend_interval(heated):
    resend_s = 3.0 - (3 * REPORT_TIME + 0.001) + REPORT_TIME  # next_pwm_time after the previous read
    sends = heated.sends("extruder")
    small_resends = 0
    for (read0, _, value0), (read1, pwm_time1, value1) in itertools.pairwise(sends):
        assert pwm_time1 == pytest.approx(read1 + REPORT_TIME)
        if abs(value1 - value0) < 0.05:
            assert read1 - read0 >= resend_s - 1e-9
            small_resends += 1
    assert small_resends > 10  # holding at 200 C: small corrections wait for the resend
    # the same signature in the Stats pwm column
    pwm = np.array([float(re.search(r"extruder: \S+ \S+ pwm=(\S+)", line)[1]) for line in heated.stats_lines])
    t_s = np.array([float(line.split()[1].rstrip(":")) for line in heated.stats_lines])
    send_t = np.array([read for read, _, _ in sends])
    for k in np.flatnonzero(np.diff(pwm)) + 1:
        sent = (send_t > t_s[k - 1]) & (send_t <= t_s[k])
        resent = any(read - prev >= resend_s - 1e-9 for read, prev in zip(send_t[1:][sent[1:]], send_t[:-1][sent[1:]]))
        assert abs(pwm[k] - pwm[k - 1]) >= 0.05 - 0.0011 or resent or sent.sum() > 1


def test_plant_input_changes_0_3_s_after_the_report():
    plant = RecordingPlant(make_plant("hotend"))
    twin = heat_up(120.0, bed=False, extruder_plant=plant)
    u = plant.u
    edges = np.arange(len(u) + 1) * TICK_S
    sends = twin.sends("extruder")
    read0, on_s, value0 = sends[0]
    assert (value0, on_s) == (1.0, pytest.approx(read0 + REPORT_TIME))
    first = int(on_s / TICK_S)  # the tick in which the pin turns on
    assert np.all(u[:first] == 0.0) and 0.0 < u[first] <= 1.0
    assert np.allclose(u[first + 1 : int(sends[1][1] / TICK_S)], 1.0)
    # every later value: the 0.1 s soft-PWM cycle from its pwm_time on carries its duty
    cycle_s = 0.1
    checked = 0
    for (_, t0, old), (_, t1, new), (_, t2, _) in zip(sends, sends[1:], sends[2:]):
        if t1 - t0 < cycle_s or t2 - t1 < cycle_s:
            continue
        before = slice(int((t1 - cycle_s) / TICK_S), int(np.ceil(t1 / TICK_S)))
        after = slice(int(t1 / TICK_S), int(np.ceil((t1 + cycle_s) / TICK_S)))
        for window, duty in ((before, old), (after, new)):
            mean = u[window].sum() * TICK_S / cycle_s
            assert mean == pytest.approx(duty, abs=2 * TICK_S / cycle_s + 1e-6)
        checked += 1
    assert checked > 5
    assert np.all(edges[np.flatnonzero(u)] >= on_s - TICK_S)


@pytest.mark.parametrize("events", [
    ((0.3, 1.0), (0.7, 0.37), (0.95, 0.0), (1.2, 0.5123)),
    ((82.308, 0.8716), (83.808, 0.7754)),  # 1.5 s apart: 1.5 / 0.1 rounds up to 15 cycles
])
def test_soft_pwm_tick_duties_integrate_the_pin(events):
    pwm = SoftPwm(0.1, 72e6)
    for time_s, value in events:
        pwm.queue(time_s, value)
    start, n, sub = int(events[0][0] / TICK_S) - 100, 2000, 256
    duties = pwm.tick_duties(start, n)
    fine_t = (start + (np.arange(n * sub) + 0.5) / sub) * TICK_S  # the pin sampled 256 times a tick
    starts = np.array(pwm.times_s)
    seg = np.searchsorted(starts, fine_t, side="right") - 1
    pin = np.mod(fine_t - starts[seg], pwm.cycle_s) < np.array(pwm.on_s)[seg]
    assert np.allclose(duties, pin.reshape(n, sub).mean(axis=1), atol=1 / sub + 1e-9)
    time_s, value = events[-1]
    assert pwm.duty_at(time_s + 0.05) == pytest.approx(value, abs=1 / pwm.cycle_ticks)


def test_verify_heater_trips_on_a_disconnected_heater_and_halts_every_heater():
    bed_plant = RecordingPlant(make_plant("bed"))
    twin = KlipperTwin([extruder_setup(), bed_setup(bed_plant)])
    twin.set_target("extruder", TARGET_C, at_s=0.0)
    twin.set_target("heater_bed", BED_C, at_s=0.0)
    twin.set_heater_mode("extruder", DISCONNECTED, at_s=200.0)
    twin.run_until(400.0)
    assert twin.halted and 200.0 < twin.shutdown_time_s < 300.0
    assert twin.shutdown_message.startswith("Heater extruder not heating at expected rate\n")
    log = twin.klippy_log()
    assert "Transition to shutdown state: Heater extruder not heating at expected rate" in log
    print(f"\nverify_heater tripped at {twin.shutdown_time_s:.1f} s")
    for name in ("extruder", "heater_bed"):
        assert twin.reports(name)[-1].t_s <= twin.shutdown_time_s
    u = bed_plant.u
    assert u[: int(twin.shutdown_time_s / TICK_S)].any()  # the bed was heating ...
    assert not u[int(np.ceil(twin.shutdown_time_s / TICK_S)) :].any()  # ... and is off from the shutdown on
    assert twin.stats_lines[-1].startswith("Stats 400.0:")  # the host keeps logging


def test_adc_range_check_shuts_down_a_stuck_on_heater():
    twin = KlipperTwin([extruder_setup()])
    twin.set_heater_mode("extruder", STUCK_ON, at_s=0.0)
    twin.run_until(600.0)
    assert twin.halted
    assert twin.shutdown_message.startswith("MCU 'mcu' shutdown: ADC out of range\n\nSensor 'extruder' temperature ")
    assert "Transition to shutdown state: MCU shutdown" in twin.klippy_log()
    temps = twin.column("extruder", "temp_c")
    assert temps[-1] > 250.0 and np.sum(temps > 250.0) == 3  # the 4th reading out of range is not reported


def test_pid_calibrate_on_the_cartridge_hotend():
    twin = KlipperTwin([extruder_setup(make_plant("hotend_cartridge"))])
    result = twin.pid_calibrate("extruder", TARGET_C)
    print(f"\nPID_CALIBRATE hotend_cartridge at {TARGET_C:.0f} C: {result.lines[0]}; Tu {result.tu_s:.1f} s, "
          f"Ku {result.ku:.4f}, peak-to-peak {result.peak_to_peak_c:.1f} C, "
          f"{result.finished_s - result.started_s:.0f} s of virtual time")
    assert re.fullmatch(r"PID parameters: pid_Kp=\d+\.\d{3} pid_Ki=\d+\.\d{3} pid_Kd=\d+\.\d{3}", result.lines[0])
    assert result.lines[1:] == ["The SAVE_CONFIG command will update the printer config file",
                                "with these parameters and restart the printer."]
    assert len(result.peaks) == 12 and result.peaks[0] == (0.0, 0.0)
    assert 20.0 <= result.tu_s <= 90.0
    assert 2 * result.kp / result.ki == pytest.approx(result.tu_s, rel=5e-3)  # a Ziegler-Nichols result
    log = twin.klippy_log()
    assert log.count("Autotune: raw=") == len(result.peaks) - 3 + 1  # from the 4th peak on, and the final pick
    kp, ki, kd = map(float, re.search(r"Autotune: final: Kp=(\S+) Ki=(\S+) Kd=(\S+)", log).groups())
    assert (round(kp, 3), round(ki, 3), round(kd, 3)) == (result.kp, result.ki, result.kd)
    assert 8 * kd / kp == pytest.approx(result.tu_s, rel=1e-4)
    assert twin.replies[0][1] == "T0:0.0 /200.0"  # the M109-style wait answers once a second
    assert twin.replies[-1][1].startswith("// PID parameters: pid_Kp=")
    heater = twin.heater("extruder")
    assert isinstance(heater.control, ControlPID) and heater.target_temp == 0.0
    assert not twin.halted


def test_pid_calibrate_interrupted_by_a_shutdown():
    twin = KlipperTwin([extruder_setup(make_plant("hotend_cartridge"))])
    twin.set_heater_mode("extruder", DISCONNECTED)
    with pytest.raises(CommandError, match="pid_calibrate interrupted"):
        twin.pid_calibrate("extruder", TARGET_C)
    assert twin.halted and twin.replies[-1][1] == "!! pid_calibrate interrupted"


def test_12_bit_adc_reads_finer_than_10_bit():
    errors = {}
    for mcu in (None, ATMEGA2560):
        twin = KlipperTwin([extruder_setup()]) if mcu is None else KlipperTwin([extruder_setup()], mcu=ATMEGA2560)
        twin.set_target("extruder", TARGET_C, at_s=0.0)
        twin.run_until(400.0)
        late = twin.column("extruder", "t_s") > 300.0
        errors[mcu] = np.abs(twin.column("extruder", "temp_c") - twin.column("extruder", "sensor_c"))[late].max()
    print(f"\nmax reading error at 200 C: 12-bit {errors[None]:.3f} C, 10-bit {errors[ATMEGA2560]:.3f} C")
    assert errors[None] < 0.3 < errors[ATMEGA2560] < 2.0


def test_replay_of_a_target_sequence_and_out_of_range_target():
    twin = KlipperTwin([extruder_setup()])
    twin.schedule_targets("extruder", [0.0, 1.0, 2.0, 100.0, 101.0], [180.0, 180.0, 180.0, 0.0, 0.0])
    twin.run_until(150.0)
    targets = twin.column("extruder", "target_c")
    t_s = twin.column("extruder", "t_s")
    assert set(targets[t_s < 100.0]) == {180.0} and set(targets[t_s > 100.0]) == {0.0}
    with pytest.raises(CommandError, match=r"Requested temperature \(400.0\) out of range \(0.0:250.0\)"):
        twin.set_target("extruder", 400.0, at_s=200.0)


def test_same_setup_same_log_and_trace():
    first, second = heat_up(300.0), heat_up(300.0)
    assert first.klippy_log() == second.klippy_log()
    for name in ("extruder", "heater_bed"):
        assert first.reports(name) == second.reports(name)
