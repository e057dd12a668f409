"""tools.logs against every captured hardware log (numbers from the README.md of the hardware logs),
against malformed input, raw klippy.log lines and the twin's own Klipper Stats output.

The captures come from the hardware_logs fixture (tests/conftest.py): without them these tests skip locally
and fail in CI.
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tools.logs import (
    LOGS_ENV,
    HeattestLog,
    LogError,
    M303Log,
    PidCalibrateResult,
    PlainLog,
    StatsLog,
    hardware_logs_dir,
    load_log,
    parse_heattest,
    parse_klipper_stats_csv,
    parse_klippy_log,
    parse_m303,
    parse_plain_csv,
)
from twin.result import RunResult


@pytest.fixture
def capture(hardware_logs: Path):
    """``capture(name)``: a capture's path; a file missing from the folder fails the test, naming it."""

    def path(name: str) -> Path:
        if not (hardware_logs / name).is_file():
            pytest.fail(f"{name} is not in {hardware_logs}; set {LOGS_ENV} to the shared/hardware_logs folder")
        return hardware_logs / name

    return path


def _error_at(path: Path, line_no: int) -> str:
    """The start of a LogError message naming this file and line, as a regex."""
    return "^" + re.escape(f"{path}:{line_no}: ")


# --- every capture loads, with the README's numbers ----------------------------------------------

# file: (sessions, Stats lines with heaters); shreypatel's 2,293 rows include 2 without heaters.
STATS = {
    "klippy_stats_chesleavens_cartesian_stm32f103.csv": (2, 4037),
    "klippy_stats_shreypatel_cartesian_stm32f407.csv": (3, 2291),
    "klippy_stats_ianryeng_corexy_ebbcan.csv": (3, 1296),
    "klippy_stats_icodextrin_ender5_creality427.csv": (3, 1333),
    "klippy_stats_jc1rb_manta_m8p.csv": (2, 769),
    "klippy_stats_claudermilk_rp2040_umbilical.csv": (3, 1357),
    "klippy_stats_jakew02_redoubt_longprint.csv": (1, 4897),
    "klippy_stats_pdegrazia_kingroon_kp3s_a.csv": (1, 749),
    "klippy_stats_pdegrazia_kingroon_kp3s_b.csv": (1, 227),
}
# file: (samples, first and last sample time, first pulse on/off times, peak)
HEATTESTS = {
    "klipper_heattest_onionheater_heattest_200.csv": (3963, 89.01, 1277.61, (89.31, 201.81), 219.0),
    "klipper_heattest_onionheater_heattest_fan_200.csv": (2124, 20.11, 657.01, (20.41, 130.21), 219.0),
    "klipper_heattest_onionheater_heattest_fan_200_2.csv": (1768, 736.31, 1266.41, (736.61, 852.71), 213.75),
    "klipper_heattest_onionheater_sample_trace.csv": (1958, 133.91, 721.01, (134.21, 249.11), 218.5),
}
# file: (samples, temperature range)
HEATSHIELD = {
    "heatshield_staircase_automationshield.csv": (8100, (28.52, 87.72)),
    "heatshield_random_staircase_automationshield.csv": (8640, (24.52, 78.00)),
}
# file: (bias lines, Ku/Tu lines, status samples, final gains, rule, tuned heater)
M303 = {
    "m303_bed_artillery_genius_pro_S60_configs641.txt": (8, 6, 2, (22.17, 1.36, 241.26), "No overshoot", "B"),
    "m303_hotend_artillery_genius_pro_S210_configs641_partial.txt": (5, 2, 2, None, "Classic PID", "T"),
    "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt": (4, 4, 17, None, "Classic PID", "T"),
    "m303_bed_and_hotend_octoprint_calibrationcompanion26_partial.txt": (2, 2, 41, (73.75, 3.09, 439.98),
                                                                         "Classic PID", "B"),
    "m303_hotend_S250_trace_marlin8081_partial.txt": (2, 1, 52, None, "Classic PID", "T"),
    "m303_hotend_single_cycle_lines_skr_marlin14486.txt": (3, 3, 0, None, None, "T"),
    "m303_hotend_C1_degenerate_marlin6316.txt": (1, 0, 0, (0.0, 0.0, 0.0), None, "T"),
    "m303_hotend_C2_degenerate_prusa_buddy5306.txt": (2, 0, 0, (0.0, 0.0, 0.0), None, "T"),
    "m303_hotend_repetier_davinci356.txt": (3, 1, 1, (25.09, 2.10, 75.08), "Classic PID", "T"),
    "marlin_m306_mpc_autotune_revo_pr23984_partial.txt": (0, 0, 5, None, None, None),
}
PID_RESULTS = "klipper_pid_calibrate_results_collection.txt"
NOT_LOGS = {  # file: what load_log says about it
    "README.md": "not a log of a known kind",
    "rrf_m303_fopdt_models_prusa_mk3s_duet3.txt": "RepRapFirmware heater model results",
}


def test_every_capture_is_covered_here(hardware_logs):
    """A new capture in the folder must get its expectations in this file."""
    known = set(STATS) | set(HEATTESTS) | set(HEATSHIELD) | set(M303) | {PID_RESULTS} | set(NOT_LOGS)
    assert {p.name for p in hardware_logs.iterdir()} == known


@pytest.mark.parametrize("name", STATS)
def test_stats_captures(name, capture):
    n_sessions, n_lines = STATS[name]
    log = load_log(capture(name))
    assert isinstance(log, StatsLog)
    assert len(log.sessions) == n_sessions
    assert all(set(session) == {"extruder", "heater_bed"} for session in log.sessions)
    assert sum(len(session["extruder"].t_s) for session in log.sessions) == n_lines
    for session in log.sessions:
        for series in session.values():
            assert np.all(np.diff(series.t_s) > 0) and np.all((series.pwm >= 0) & (series.pwm <= 1))
            parts = series.segments()
            assert sum(len(p.t_s) for p in parts) == len(series.t_s)
            assert all(np.all(np.diff(p.t_s) <= 5.0) for p in parts)
    assert log.meta["klipper_version"].startswith("v0.1")
    assert {"extruder", "heater_bed"} <= set(log.meta["config"])


def test_stats_numbers_from_the_readme(capture):
    ches = load_log(capture("klippy_stats_chesleavens_cartesian_stm32f103.csv"))
    bed = ches.sessions[0]["heater_bed"]
    assert bed.temp_c[bed.target_c == 65].min() < 27 and bed.temp_c.max() >= 65  # bed 26 -> 65 C
    assert {150, 200, 210, 215, 220} <= set(ches.sessions[0]["extruder"].target_c)
    assert [len(s["extruder"].segments()) for s in ches.sessions] == [2, 3]  # idle gaps: 222 s; 14 and 47 s
    assert ches.meta["config"]["extruder"]["pid_kp"] == "29.229"

    ian = load_log(capture("klippy_stats_ianryeng_corexy_ebbcan.csv"))
    assert ian.meta["config"]["heater_bed"]["max_power"] == "0.8"
    assert max(s["heater_bed"].pwm.max() for s in ian.sessions) == pytest.approx(0.8)

    redoubt = load_log(capture("klippy_stats_jakew02_redoubt_longprint.csv")).sessions[0]
    assert redoubt["heater_bed"].pwm.max() <= 0.6 and redoubt["heater_bed"].temp_c.max() >= 110
    assert redoubt["extruder"].t_s[-1] - redoubt["extruder"].t_s[0] == pytest.approx(40432, abs=1)


@pytest.mark.parametrize("name", HEATTESTS)
def test_heattest_captures(name, capture):
    n, t_first_s, t_last_s, (on_s, off_s), peak_c = HEATTESTS[name]
    log = load_log(capture(name))
    assert isinstance(log, HeattestLog)
    assert (len(log.t_s), log.t_s[0], log.t_s[-1]) == (n, pytest.approx(t_first_s), pytest.approx(t_last_s))
    assert log.pwm_events[:2] == [(pytest.approx(on_s), 1.0), (pytest.approx(off_s), 0.0)]
    assert log.temp_c.max() == peak_c
    assert np.all(log.pwm[(log.t_s >= on_s) & (log.t_s < off_s)] == 1.0)
    assert np.median(np.diff(log.t_s)) == pytest.approx(0.3)


def test_heattest_overshoot_after_cut_off(capture):
    """heattest_200: cut at 200.5 C, peak 219.0 C at 221.9 s, ~20 s later (README section B)."""
    log = load_log(capture("klipper_heattest_onionheater_heattest_200.csv"))
    cut = int(np.argmax(log.pwm[1:] < log.pwm[:-1])) + 1
    assert (log.t_s[cut], log.temp_c[cut]) == (pytest.approx(201.81), 200.5)
    peak = cut + int(np.argmax(log.temp_c[cut : cut + 200]))
    assert (log.t_s[peak], log.temp_c[peak]) == (pytest.approx(221.91), 219.0)


@pytest.mark.parametrize("name", HEATSHIELD)
def test_heatshield_captures(name, capture):
    n, (low_c, high_c) = HEATSHIELD[name]
    log = load_log(capture(name))
    assert isinstance(log, PlainLog) and log.duty_from_percent
    assert len(log.t_s) == n and np.all(np.diff(log.t_s) == 2.0)
    assert (log.temp_c.min(), log.temp_c.max()) == (low_c, high_c)
    assert (log.duty.min(), log.duty.max()) == (0.0, 1.0)


@pytest.mark.parametrize("name", M303)
def test_m303_captures(name, capture):
    n_bias, n_ku, n_status, final_gains, rule, heater = M303[name]
    log = load_log(capture(name))
    assert isinstance(log, M303Log)
    assert sum(c.bias is not None for c in log.cycles) == n_bias
    assert sum(c.ku is not None for c in log.cycles) == n_ku
    assert len(log.status) == n_status
    assert log.final_gains == final_gains and log.rule == rule
    assert {c.heater for c in log.cycles} <= {heater, "?"}  # "?": printed before anything says which heater
    assert all(0 <= s.power <= log.power_max for s in log.status)


def test_m303_details(capture):
    bed = load_log(capture("m303_bed_artillery_genius_pro_S60_configs641.txt"))
    assert bed.commands == [(5, "M303 E-1 C8 S60")]
    assert [c.bias for c in bed.cycles] == [34, 24, 21, 20, 20, 20, 20, 20]
    assert (bed.cycles[2].ku, bed.cycles[2].tu_s, bed.cycles[2].kp) == (97.91, 36.48, 19.58)
    assert [s.heater for s in bed.status] == ["B", "B"] and bed.status[0][1:] == (59.85, 0.0, 34, "B")

    prusa = load_log(capture("m303_bed_and_hotend_octoprint_calibrationcompanion26_partial.txt"))
    assert [(c.ku, c.tu_s) for c in prusa.cycles] == [(132.30, 45.37), (122.92, 47.73)]
    assert prusa.commands == [(55, "M303 E0 C5 S215")]
    hotend = [s for s in prusa.status if s.heater == "T"]
    assert len(hotend) == 10 and all(s.power == 127 for s in hotend) and math.isnan(hotend[0].target_c)
    assert any(h.startswith("Prusa-Firmware") for h in prusa.firmware_hints)

    s250 = load_log(capture("m303_hotend_S250_trace_marlin8081_partial.txt"))
    assert s250.skipped == [(36, s250.skipped[0][1])]  # "@:1", cut out of "@:127 B@:0"
    assert {s.power for s in s250.status} == {127, 70, 87, 79}
    assert (s250.cycles[-1].bias, s250.cycles[-1].d, s250.cycles[-1].kd) == (206, 48, 42.96)

    repetier = load_log(capture("m303_hotend_repetier_davinci356.txt"))
    assert repetier.power_max == 255 and repetier.status[0][1:] == (200.0, 0.0, 86, "T")
    assert any("failed" in h for h in repetier.firmware_hints)

    mpc = load_log(capture("marlin_m306_mpc_autotune_revo_pr23984_partial.txt"))
    assert [s.temp_c for s in mpc.status] == [148.08, 151.23, 154.96, 157.94, 160.87]
    assert {(s.target_c, s.power) for s in mpc.status} == {(200.0, 127)}


def test_pid_calibrate_results(capture):
    results = load_log(capture(PID_RESULTS))
    assert all(isinstance(r, PidCalibrateResult) for r in results)
    assert len(results) == 20  # [1]-[4], four of [5], twelve pid_kp rows of [6] (KP3S is in another form)
    by_line = {r.line_no: r for r in results}
    # the file's "derived" lines: Tu = 2Kp/Ki = 8Kd/Kp and the peak-to-peak swing
    for line_no, tu_s, p_p_c in [(7, 98.4, 5.9), (12, 1.20, 17.7), (20, 57.6, 21.1), (24, 44.4, 28.6),
                                 (47, 17.40, 13.3), (50, 5.40, 9.0), (51, 63.9, 5.35), (58, 49.8, 4.0)]:
        r = by_line[line_no]
        assert r.tu_s == pytest.approx(tu_s, rel=2e-3) and r.tu_from_kd_s == pytest.approx(tu_s, rel=2e-3)
        assert r.peak_to_peak_c == pytest.approx(p_p_c, abs=0.05)
    stock = by_line[31]  # [5]'s "hotend from" (a stock PID_CALIBRATE): "the two Tu do not agree"
    assert (stock.tu_s, stock.tu_from_kd_s) == (pytest.approx(13.6, abs=0.05), pytest.approx(6.66, abs=0.01))
    assert (by_line[51].max_power, by_line[58].max_power) == (0.8, 0.6)
    assert by_line[7].heater == "heater_bed" and "issues/603" in by_line[7].source
    # every SAVE_CONFIG row is a genuine PID_CALIBRATE result and equals the Stats capture's config
    for r in results:
        if r.source.startswith("[6]"):
            assert r.tu_s == pytest.approx(r.tu_from_kd_s, rel=1e-3)
            config = load_log(capture(r.source.split()[1])).meta["config"][r.heater]
            assert [float(config[k]) for k in ("pid_kp", "pid_ki", "pid_kd")] == [r.kp, r.ki, r.kd]


@pytest.mark.parametrize("name", NOT_LOGS)
def test_files_that_are_not_logs(name, capture):
    with pytest.raises(LogError, match=re.escape(NOT_LOGS[name])):
        load_log(capture(name))


def test_missing_logs_folder_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv(LOGS_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError, match=f"hardware logs not found at .*nowhere: set {LOGS_ENV}"):
        hardware_logs_dir()


# --- malformed input -----------------------------------------------------------------------------

STATS_HEADER = "session,t_host_s,print_time_s,extruder_target,extruder_temp,extruder_pwm"


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("row, what", [
    ("1,3.0,1.0,210,abc,0.5", "extruder temp: 'abc' is not a number"),
    ("1,3.0,1.0,210,nan,0.5", "extruder temp: 'nan' is not a finite number"),
    ("1,3.0,1.0,210,25.0", "5 columns where the header has 6"),
    ("1,3.0,1.0,210,,0.5", "heater extruder: no temp"),
    ("1,3.0,1.0,210,25.0,1.5", "extruder pwm = 1.5 is outside 0..1"),
    ("1,1.5,1.0,210,25.0,0.5", "time 1.5 s does not increase (previous sample: 2 s)"),
    ("1,3.0,1.0,210,25.0,\"0.5", "not a CSV line"),
])
def test_malformed_stats_csv_line(tmp_path, row, what):
    path = _write(tmp_path, "stats.csv", f"# a comment\n{STATS_HEADER}\n1,1.0,0.0,0,20.0,0.000\n"
                  f"1,2.0,0.5,210,21.0,1.000\n{row}\n")
    with pytest.raises(LogError, match=_error_at(path, 5) + re.escape(what)):
        load_log(path)


def test_stats_csv_sessions_and_empty_lines(tmp_path):
    """A new session id starts a session (time may restart); a line without heaters is left out."""
    path = _write(tmp_path, "stats.csv", f"{STATS_HEADER}\n0,10.0,0.0,0,20.0,0.000\n0,11.0,,,,\n"
                  "0,19.0,0.0,200,25.0,1.000\n2,3.0,1.0,200,30.0,1.000\n")
    log = parse_klipper_stats_csv(path)
    assert [list(s["extruder"].t_s) for s in log.sessions] == [[10.0, 19.0], [3.0]]
    assert [list(p.t_s) for p in log.sessions[0]["extruder"].segments()] == [[10.0], [19.0]]


def test_truncated_last_line(tmp_path):
    path = _write(tmp_path, "stats.csv", f"{STATS_HEADER}\n1,1.0,0.0,0,20.0,0.000\n1,2.0,0.5,210,21")
    with pytest.raises(LogError, match=_error_at(path, 3) + "the last line has no newline"):
        load_log(path)
    path = _write(tmp_path, "plain.csv", "t_s,temp_c,duty\n0,20.0,0.5\n2,20.5,0.")
    with pytest.raises(LogError, match=_error_at(path, 3) + "the last line has no newline"):
        parse_plain_csv(path)


@pytest.mark.parametrize("text, line_no, what", [
    ("hello world\nthis is no log\n", 1, "not a log of a known kind"),
    ("# only a comment\n", 1, "no data lines"),
    ("", 1, "no data lines"),
    ("1,2\n3,4\n", 1, "not a log of a known kind"),
])
def test_garbage(tmp_path, text, line_no, what):
    path = _write(tmp_path, "garbage.txt", text)
    with pytest.raises(LogError, match=_error_at(path, line_no) + what):
        load_log(path)


def test_binary_garbage(tmp_path):
    path = tmp_path / "garbage.bin"
    path.write_bytes(b"t_s,temp_c,duty\n0,20,0\n\xff\xfe\x00\x81\n")
    with pytest.raises(LogError, match=_error_at(path, 3) + "not UTF-8 text"):
        load_log(path)


def test_klipper_heattest_file(tmp_path):
    """WRITE_FILE output as pid_calibrate.py writes it: events first, no newline at the end."""
    path = _write(tmp_path, "heattest.txt", "pwm: 10.300 1.000\npwm: 11.200 0.000\n"
                  "10.000 25.000\n10.300 25.250\n10.600 26.000\n10.900 27.500\n11.200 28.750\n11.500 29.000")
    log = load_log(path)
    assert isinstance(log, HeattestLog)
    assert log.pwm_events == [(10.3, 1.0), (11.2, 0.0)]
    assert list(log.pwm) == [0.0, 1.0, 1.0, 1.0, 0.0, 0.0]
    bad = _write(tmp_path, "bad.txt", "pwm: 10.300 1.000\n10.000 25.000\n10.300 25 .250\n")
    with pytest.raises(LogError, match=_error_at(bad, 3) + "expected '<time> <temp>'"):
        parse_heattest(bad)
    bad = _write(tmp_path, "bad.txt", "pwm: 10.300 x\n10.000 25.000\n")
    with pytest.raises(LogError, match=_error_at(bad, 1) + "pwm: 'x' is not a number"):
        parse_heattest(bad)


def test_plain_csv(tmp_path):
    log = load_log(_write(tmp_path, "a.csv", "# duty in percent\ntime,temperature,duty_pct\n0,20,50\n2,21,100\n"))
    assert isinstance(log, PlainLog) and log.duty_from_percent and list(log.duty) == [0.5, 1.0]
    log = load_log(_write(tmp_path, "b.csv", "0,20,0.5\n2,21,1\n"))
    assert not log.duty_from_percent and list(log.t_s) == [0.0, 2.0]
    path = _write(tmp_path, "c.csv", "0,20,0.5\n2,21,50\n")
    with pytest.raises(LogError, match=_error_at(path, 2) + ".*name the column duty_pct"):
        load_log(path)
    path = _write(tmp_path, "d.csv", "when,temp_c,duty\n0,20,0.5\n")
    with pytest.raises(LogError, match=_error_at(path, 1) + "header when,temp_c,duty"):
        parse_plain_csv(path)


@pytest.mark.parametrize("line, what", [
    ("Recv:  bias: 34 d: x min: 59.81 max: 61.13", "d: 'x' is not a number"),
    ("Recv:  bias: 34.5 d: 34 min: 59.81 max: 61.13", "bias: '34.5' is not an integer"),
    ("Recv:  bias: 34 d: 34 min: 59.81", "a bias line without bias, d, min and max"),
    ("Recv:  Ku: 97.91", "a Ku line without Ku and Tu"),
    ("Recv:  Kp: 19.58 Ki: abc Kd: 238.13", "Ki: 'abc' is not a number"),
    ("Recv:  T:abc /0.00 B:59.85 /0.00 @:0 B@:34", "T temperature: 'abc' is not a number"),
    ("Recv: #define DEFAULT_bedKp 2x", "DEFAULT_bedKp: '2x' is not a number"),
])
def test_malformed_m303_line(tmp_path, line, what):
    path = _write(tmp_path, "m303.txt", f"# header\nSend: M303 E-1 C8 S60\nRecv: PID Autotune start\n{line}\n")
    with pytest.raises(LogError, match=_error_at(path, 4) + re.escape(what)):
        parse_m303(path)


def test_malformed_pid_results(tmp_path):
    text = "# [1] https://example.org/1 - extruder\npid_kp = 22.2\npid_ki = 1.08\n# [2] https://example.org/2\n"
    path = _write(tmp_path, "pid.txt", text + "Autotune: final: Kp=1 Ki=2 Kd=3\n")
    with pytest.raises(LogError, match=_error_at(path, 2) + "Kp, Ki and Kd are not all given"):
        load_log(path)
    path = _write(tmp_path, "pid.txt", "Recv: // PID parameters: pid_Kp=22.019 pid_Ki=x pid_Kd=3.303\n")
    with pytest.raises(LogError, match=_error_at(path, 1) + "Ki: 'x' is not a number"):
        load_log(path)


# --- raw klippy.log and the twin's own output ----------------------------------------------------

KLIPPY_LOG = """\
Starting Klippy...
Args: ['/home/pi/klipper/klippy/klippy.py', '/home/pi/printer_data/config/printer.cfg', '-l', '/tmp/klippy.log']
Git version: 'v0.12.0-85-gd785b396'
Start printer at Sat Sep 28 14:19:38 2024 (1727565578.2 3131.2)
===== Config file =====
[extruder]
heater_pin = PA1
control = pid
pid_kp = 22.2  # Klipper's example value
pid_ki = 1.08
pid_kd = 114
# a comment in printer.cfg

[heater_bed]
max_power: 0.8

[gcode_macro START]
gcode:
  M190 S60

#*# <---------------------- SAVE_CONFIG ---------------------->
#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.
#*#
#*# [extruder]
#*# pid_kp = 24.831
=======================
Loaded MCU 'mcu' 117 commands (v0.12.0-85-gd785b396 / gcc: (15:7-2018-q2-6) 7.3.1 20180622)
Stats 3134.2: gcodein=0  mcu: mcu_awake=0.004 mcu_task_avg=0.000010 mcu_task_stddev=0.000009 bytes_write=1204 \
bytes_read=5620 bytes_retransmit=9 bytes_invalid=0 send_seq=131 receive_seq=131 retransmit_seq=2 srtt=0.001 rttvar=0.000 \
rto=0.025 ready_bytes=0 upcoming_bytes=0 freq=71999434 heater_bed: target=0 temp=24.1 pwm=0.000 \
raspberry_pi: temp=45.2 sysload=0.52 cputime=2.118 memavail=712412 print_time=3.561 buffer_time=0.000 \
print_stall=0 extruder: target=200 temp=25.9 pwm=1.000
Stats 3135.2: gcodein=0 heater_bed: target=0 temp=24.1 pwm=0.000 print_time=4.561 extruder: target=200 temp=27.0 pwm=1.000
Stats 3136.2: gcodein=0 heater_bed: target=0 temp=24.2 pwm=0.000 print_time=5.561 extruder: target=200 temp=28.4 pwm=1.000
INFO:root:Stats 3150.2: gcodein=0 heater_bed: target=60 temp=24.2 pwm=1.000 print_time=19.561 extruder: target=0 temp=60.1 pwm=0.000
INFO:root:Stats 3151.2: gcodein=0 heater_bed: target=60 temp=24.4 pwm=1.000 print_time=20.561 extruder: target=0 temp=59.0 pwm=0.000
Stats 3152.2: gcodein=0 sysload=0.52
Restarting printer
Start printer at Sat Sep 28 14:25:01 2024 (1727565901.0 3454.0)
Stats 3455.0: gcodein=0 heater_bed: target=0 temp=50.1 pwm=0.000 extruder: target=0 temp=51.0 pwm=0.000
Stats 3456.0: gcodein=0 heater_bed: target=0 temp=50.0 pwm=0.000 extruder: target=0 temp=50.9 pwm=0.000
Stats 12.5: gcodein=0 heater_bed: target=0 temp=22.0 pwm=0.000 extruder: target=210 temp=22.5 pwm=1.000
"""


def test_raw_klippy_log(tmp_path):
    """Sessions at "Start printer at" and where host time restarts (reboot); a gap is a segment."""
    log = load_log(_write(tmp_path, "klippy.log", KLIPPY_LOG))
    assert isinstance(log, StatsLog)
    assert [list(s["extruder"].t_s) for s in log.sessions] == [
        [3134.2, 3135.2, 3136.2, 3150.2, 3151.2], [3455.0, 3456.0], [12.5]]
    first = log.sessions[0]
    assert set(first) == {"extruder", "heater_bed"}  # raspberry_pi (temp only) is a sensor
    assert list(first["extruder"].temp_c) == [25.9, 27.0, 28.4, 60.1, 59.0]
    assert list(first["heater_bed"].pwm) == [0.0, 0.0, 0.0, 1.0, 1.0]
    assert [len(p.t_s) for p in first["extruder"].segments()] == [3, 2]
    assert log.meta["klipper_version"] == "v0.12.0-85-gd785b396"
    assert log.meta["config"]["extruder"]["pid_kp"] == "24.831"  # SAVE_CONFIG's value wins
    assert log.meta["config"]["extruder"]["pid_ki"] == "1.08"
    assert log.meta["config"]["heater_bed"] == {"max_power": "0.8"}


@pytest.mark.parametrize("line, what", [
    ("Stats 3137.2: extruder: target=200 temp=abc pwm=1.000", "extruder temp: 'abc' is not a number"),
    ("Stats 3137.2: extruder: target=200 temp=28.0", None),  # no pwm=: a sensor, not a heater
    ("Stats 3137.2: extruder: temp=28.0 pwm=0.5", "heater extruder: no target"),
    ("INFO:root:Stats x: extruder: target=200 temp=28.0 pwm=1.0", "Stats time: 'x' is not a number"),
])
def test_malformed_stats_line(tmp_path, line, what):
    lines = KLIPPY_LOG.splitlines()
    lines.insert(30, line)
    path = _write(tmp_path, "klippy.log", "\n".join(lines) + "\n")
    if what is None:
        assert len(parse_klippy_log(path).sessions[0]["extruder"].t_s) == 5
    else:
        with pytest.raises(LogError, match=_error_at(path, 31) + re.escape(what)):
            parse_klippy_log(path)


def test_the_twins_klipper_stats_parse(tmp_path):
    """A run result's Stats lines read back: one session, one line per second, values as printed."""
    t_s = np.arange(60) * 0.16384
    result = RunResult.from_columns(t_s, {
        "hotend": {"target_c": np.full(60, 210.0), "measured_c": 25.0 + 2.0 * t_s,
                   "duty": np.where(t_s < 5.0, 1.0, 0.5)},
        "bed": {"target_c": np.full(60, 60.0), "measured_c": np.full(60, 24.0), "duty": np.full(60, 0.25)}})
    log = load_log(_write(tmp_path, "twin.log", result.to_klipper_stats()))
    assert isinstance(log, StatsLog) and len(log.sessions) == 1
    hotend, bed = log.sessions[0]["extruder"], log.sessions[0]["heater_bed"]
    assert list(np.floor(hotend.t_s)) == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    assert np.all(hotend.target_c == 210.0) and np.all(bed.pwm == 0.25)
    assert hotend.temp_c == pytest.approx(25.0 + 2.0 * hotend.t_s, abs=0.15)
    assert list(hotend.pwm) == [1.0] * 4 + [0.5] * 5


# --- property: any line gives a result or a LogError naming the file -----------------------------

BASES = {  # a small valid file of each kind, with a line to insert
    "stats.csv": f"{STATS_HEADER}\n1,1.0,0.0,0,20.0,0.000\n{{}}\n1,9.0,0.5,210,21.0,1.000\n",
    "plain.csv": "t_s,temp_c,duty\n0,20.0,0.5\n{}\n9,21.0,0.5\n",
    "heattest.txt": "pwm: 1.000 1.000\n0.700 20.000\n{}\n9.000 25.000\n",
    "klippy.log": "Start printer at now\nStats 1.0: extruder: target=0 temp=20.0 pwm=0.000\n{}\n",
    "m303.txt": "Recv:  bias: 34 d: 34 min: 59.81 max: 61.13\n{}\nRecv:  Kp: 19.58 Ki: 1.07 Kd: 238.13\n",
    "pid.txt": "pid_kp = 22.2\n{}\npid_ki = 1.08\npid_kd = 114\n",
}
NEAR_MISSES = ["Stats 0.5: extruder: target=1 temp=2 pwm=3", " T:1 /2 B:3 /4 @:5", "bias: 1 d: 2", "Ku: 1 Tu: x",
               "pwm: 2 0.5", "#define DEFAULT_Kp", "0,nan,1", "1,2,3,4", "Kp=1 Ki=2", "Start printer at"]
ANY_LINE = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\n"), max_size=80)


@given(line=ANY_LINE | st.sampled_from(NEAR_MISSES))
def test_any_line_reads_or_raises_log_error(tmp_path_factory, line):
    folder = tmp_path_factory.mktemp("logs")
    for name, base in BASES.items():
        path = _write(folder, name, base.format(line))
        try:
            load_log(path)
        except LogError as e:
            assert str(e).startswith(f"{path}:")
