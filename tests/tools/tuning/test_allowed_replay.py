"""Which replay judges a plant fitted to a klippy.log of an [extruder] (a section with the printer's PID
settings): the twin's closed loop with the printer's gains where the printer's loop drove a heat-up, and the
plant under the logged duty where the log is PID_CALIBRATE alone, whose relay (the target moved between
TARGET and TARGET - 5 C) is no heat-up of the printer's loop. The logs are the twin's own klippy.log (Klipper's
PID_CALIBRATE and heater loop, ported) with the config dump klippy writes at its start."""

from pathlib import Path

from tools.ident.log_fit import LogFitOptions, fit_log
from tools.logs import load_log
from tools.tuning.allowed import heater_settings, replay
from twin.klipper_twin import KlipperTwin, extruder_setup

CONFIG_DUMP = """\
Starting Klippy...
===== Config file =====
[extruder]
heater_pin = PA1
sensor_type = EPCOS 100K B57560G104F
control = pid
pid_kp = 21.527
pid_ki = 1.063
pid_kd = 108.982
min_temp = 0
max_temp = 250
=======================
"""


def klippy_log(tmp_path: Path, twin: KlipperTwin) -> Path:
    path = tmp_path / "klippy.log"
    path.write_text(CONFIG_DUMP + twin.klippy_log())
    return path


def judged(path: Path):
    log = load_log(path)
    fitted = fit_log(log, LogFitOptions(heater="extruder", model="two_node"))
    return replay(log, fitted, heater_settings(log, "extruder"))


def test_a_pid_calibrate_log_is_replayed_under_its_logged_duty(tmp_path):
    twin = KlipperTwin([extruder_setup()])
    twin.run_until(20.0)
    twin.pid_calibrate("extruder", 210.0)
    verdict = judged(klippy_log(tmp_path, twin))
    assert verdict.what == "the plant under the logged duty" and verdict.passed, verdict
    assert verdict.rows[0][0] == "trace RMSE C"


def test_a_heat_up_under_the_printers_loop_is_replayed_in_the_twins_closed_loop(tmp_path):
    twin = KlipperTwin([extruder_setup(pid_kp=21.527, pid_ki=1.063, pid_kd=108.982)])
    twin.run_until(20.0)
    twin.set_target("extruder", 210.0)
    twin.run_until(400.0)
    verdict = judged(klippy_log(tmp_path, twin))
    assert verdict.what.startswith("the twin's closed loop with the printer's gains") and verdict.passed, verdict
    assert [row[0] for row in verdict.rows] == ["heat-up s", "overshoot C", "hold RMS twin-log C"]
