"""tools/validation/compare.py, tools/cli/compare.py and tools/docs/validation.py on the real hardware logs.

The logs come from the hardware_logs fixture: without them these tests skip locally and fail in CI.
"""

import math

import numpy as np
import pytest

from tools.cli import compare as compare_cli
from tools.validation import compare
from tools.docs import validation
from tools.validation.doc_compare import compare_docs
from tools.logs import load_log

CHES = "klippy_stats_chesleavens_cartesian_stm32f103.csv"


def test_open_loop_check_gives_finite_numbers(hardware_logs):
    r = compare.open_loop_check(hardware_logs, both_ways=False)
    assert math.isfinite(r.fit_rmse_c) and r.fit_rmse_c < 3.0  # the no-fan fit itself is good
    (row,) = r.rows
    assert row["predicted"] == compare.ONION_FAN_TEST
    for key in ("fan_xfer_w_k", "fit_rmse_c", "rmse_c", "max_err_c", "peak_twin_c"):
        assert math.isfinite(row[key]), key
    assert row["fan_xfer_w_k"] > 0 and row["max_err_c"] >= row["rmse_c"] > 0


def test_closed_loop_replay_chesleavens_bed(hardware_logs):
    r = compare.closed_loop_check(hardware_logs / CHES, "heater_bed")
    assert r.info.kp == pytest.approx(54.027) and r.info.sensor == "EPCOS 100K B57560G104F"
    assert r.shutdown is None
    for m in (r.log, r.twin):
        for value in (m.heatup_s, m.overshoot_c, m.hold_rms_c, m.steady_pwm):
            assert math.isfinite(value)
    assert math.isfinite(r.hold_rmse_c) and set(r.checks) == {"heat-up", "overshoot", "hold"}
    assert 60.0 < r.log.heatup_s < 200.0  # README: 26 -> 65 C in ~128 s


def test_target_changes_are_set_halfway_between_stats_lines():
    t = np.array([10.0, 11.0, 12.0, 13.5, 14.5])
    target = np.array([0.0, 0.0, 150.0, 150.0, 220.0])
    assert compare.target_times_s(t, target).tolist() == [10.0, 11.0, 11.5, 13.5, 14.0]


def test_lead_in_skips_the_readings_before_klippers_first_report(hardware_logs):
    """jc1rb's sessions start with temp 0.0 lines (no report yet): a lead-in from there would start
    the plant at 0 C and trip the ADC range check."""
    _, windows = compare.heatup_windows(load_log(hardware_logs / "klippy_stats_jc1rb_manta_m8p.csv"), "extruder")
    for w in windows:
        assert w.lead_t_s.size and np.all(w.lead_temp_c > 0.0)
        assert w.t_s[0] - compare.LEAD_IN_S <= w.lead_t_s[0] < w.t_s[0]


def test_replay_from_a_warm_hold_heats_at_once(hardware_logs):
    """chesleavens' held-out heat-up starts from a hold at 150 C: the log sends full power at the
    target change. Without the lead-in the twin's PID started at Klipper's 25 C and its derivative
    held the pwm at 0 for 3 s."""
    r = compare.closed_loop_check(hardware_logs / CHES, "extruder")
    assert not r.same_segment and r.target_c == 220
    t, log_temp, twin_temp, log_pwm, twin_pwm = r.trace
    assert log_pwm[1] == 1.0 and twin_pwm[1] == r.info.max_power
    assert abs(twin_temp[0] - log_temp[0]) < 2.0  # the lead-in held 150 C as the printer did


def test_miss_evidence_replays_the_missed_heat_up_in_sample(hardware_logs):
    path = hardware_logs / "klippy_stats_ianryeng_corexy_ebbcan.csv"
    r = compare.closed_loop_check(path, "extruder")
    assert not r.same_segment and not r.checks["overshoot"]
    e = compare.miss_evidence(path, r)
    assert e.own is not None and e.own.same_segment and e.own.replay_label == r.replay_label
    assert e.own.fit_label.startswith("session 0,") and r.fit_label.startswith("session 1,")
    assert not e.own.checks["overshoot"]  # the model misses it fitted on it too
    assert math.isfinite(e.heating_rate_sigmas) and all(0.0 < d < 1.0 for d in e.hold_duty)
    assert r.log.hold_rms_c > compare.GOAL_HOLD_RMSE_C  # the log's own limit cycle about 150 C
    note = compare.miss_note(e)
    assert "held-out replay of session 0" in note and "even fitted on it" in note


def test_miss_evidence_of_an_in_sample_replay_is_the_replay_itself(hardware_logs):
    path = hardware_logs / "klippy_stats_jakew02_redoubt_longprint.csv"
    r = compare.closed_loop_check(path, "heater_bed")
    e = compare.miss_evidence(path, r)
    assert r.same_segment and e.own is None
    assert "in-sample replay" in compare.miss_note(e) and "max_power 0.6" in compare.miss_note(e)


def test_autotune_cross_check_returns_tu(hardware_logs):
    r = compare.autotune_check(hardware_logs / CHES, "extruder")
    assert r.tu_log_s == pytest.approx(2 * 29.229 / 3.360)
    assert math.isfinite(r.tu_twin_s) and r.tu_twin_s > 0
    assert all(math.isfinite(t) and t > 0 for t in r.tu_band_s)  # 180 and 240 C, both within max_temp
    low, high = sorted(r.tu_band_s)
    assert r.passed_in_band == (0.85 * low <= r.tu_log_s <= 1.15 * high)


@pytest.mark.parametrize("name", ["m303_hotend_C1_degenerate_marlin6316.txt",
                                  "rrf_m303_fopdt_models_prusa_mk3s_duet3.txt",
                                  "klipper_pid_calibrate_results_collection.txt"])
def test_twin_compare_unusable_exits_2(hardware_logs, name, capsys):
    assert compare_cli.main([str(hardware_logs / name)]) == 2
    err = capsys.readouterr().err
    assert "not usable" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_twin_compare_missing_file_exits_2(tmp_path, capsys):
    assert compare_cli.main([str(tmp_path / "nope.csv")]) == 2
    assert "not usable" in capsys.readouterr().err


@pytest.mark.slow
def test_validation_doc_is_up_to_date(hardware_logs):
    """Verdicts, words and integers exactly, decimals within tools/validation/doc_compare.py's tolerance: the
    fits' last bits depend on the BLAS kernel (OPENBLAS_CORETYPE), never the verdicts."""
    mismatches = compare_docs(validation.render(hardware_logs), validation.DOC.read_text())
    assert not mismatches, ("docs/validation.md is stale (run python -m tools.docs.validation):\n"
                            + "\n".join(map(str, mismatches)))


# A row of docs/validation.md as rendered on the Haswell kernel and on SkylakeX (an AVX-512 machine).
HASWELL_ROW = ("| `klippy_stats_icodextrin_ender5_creality427.csv` | heater_bed | session 2, 535.3..728.4 s | "
               "session 2, 535..728 s | 50 | 81.0 / 79.5 | -1.9 % | 1.4 / 1.1 | 0.32 | 0.205 / 0.211 | pass |")
SKYLAKEX_ROW = HASWELL_ROW.replace("| 0.32 | 0.205 / 0.211 |", "| 0.31 | 0.205 / 0.205 |")


def test_doc_compare_accepts_the_measured_kernel_spread():
    assert compare_docs(SKYLAKEX_ROW, HASWELL_ROW) == []


@pytest.mark.parametrize("changed", [
    HASWELL_ROW.replace("| -1.9 % | 1.4 / 1.1 | 0.32 | 0.205 / 0.211 | pass |",
                        "| -1.9 % | 1.4 / 1.1 | 0.32 | 0.205 / 0.211 | **miss** |"),  # a verdict
    HASWELL_ROW.replace("| 50 |", "| 55 |"),  # an integer (a target)
    HASWELL_ROW.replace("81.0 / 79.5", "81.0 / 75.0"),  # a number beyond 5 %
    HASWELL_ROW.replace("| 0.32 |", "| 0.28 |"),  # 4 steps and 12 %: beyond both
    HASWELL_ROW.replace("session 2, 535..728 s", "session 1, 535..728 s"),  # a label
    HASWELL_ROW + " extra |",  # a column
])
def test_doc_compare_rejects_real_changes(changed):
    assert compare_docs(changed, HASWELL_ROW)


def test_doc_compare_counts_lines():
    assert compare_docs("a\nb", "a")


@pytest.mark.parametrize("plot, says", [("missing_folder/replay.png", "does not exist"),
                                        ("replay.xyz", "unknown plot format")])
def test_twin_compare_bad_plot_path_fails_before_the_work(hardware_logs, tmp_path, capsys, plot, says):
    """Checked by argparse before the log is even read: no traceback after 15 s of replay."""
    with pytest.raises(SystemExit) as stop:
        compare_cli.main([str(hardware_logs / CHES), "--plot", str(tmp_path / plot)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert says in err and "--plot" in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_twin_compare_help_has_examples(capsys):
    with pytest.raises(SystemExit):
        compare_cli.main(["--help"])
    assert "examples:\n  twin-compare " in capsys.readouterr().out
