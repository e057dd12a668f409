"""twin-sim end to end: defaults, each firmware, outputs, and clear errors on bad input."""

import re

import pytest

from tools.sim import main


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_defaults_print_metrics_and_write_trace_and_plot(capsys, tmp_path):
    code, out, err = run(capsys, "--out", str(tmp_path))
    assert code == 0, err
    assert out.startswith("twin-sim: heat_hold, firmware pid, 600 s virtual, seed 0\n")
    assert "hotend (firmware-measured temperature):" in out and "bed (firmware-measured temperature):" in out
    assert re.search(r"^target_c\s+210\.00$", out, re.M)
    rise = float(re.search(r"^rise_time_s\s+(\S+)$", out, re.M).group(1))
    assert 30 < rise < 150
    csv = (tmp_path / "heat_hold_pid.csv").read_text()
    assert csv.startswith("t_s,hotend_target_c,hotend_measured_c,")
    assert len(csv.splitlines()) > 3600  # one row per 0.164 s reading
    png = (tmp_path / "heat_hold_pid.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("firmware", ["pid", "pid_float", "bangbang", "fuzzy_pi"])
def test_each_firmware_reaches_the_target(capsys, tmp_path, firmware):
    code, out, err = run(capsys, "--firmware", firmware, "--duration", "200", "--no-bed", "--no-plot",
                         "--out", str(tmp_path))
    assert code == 0, err
    assert re.search(r"^reached\s+yes$", out, re.M)
    steady = float(re.search(r"^steady_state_error_c\s+(\S+)$", out, re.M).group(1))
    assert abs(steady) < 3.0


def test_protection_trip_is_reported(capsys, tmp_path):
    code, out, _ = run(capsys, "--scenario", "cartridge_falls_out", "--no-plot", "--out", str(tmp_path))
    assert code == 0
    assert re.search(r"^protection at \d+\.\d s: Thermal Runaway on E0; the board halted", out, re.M)


def test_klipper_log_and_plant_overrides(capsys, tmp_path):
    log = tmp_path / "klippy.log"
    code, out, err = run(capsys, "--plant", "hotend", "--set", "power_w=60", "--target", "200", "--duration", "60",
                         "--no-plot", "--out", str(tmp_path), "--klipper-log", str(log))
    assert code == 0, err
    lines = log.read_text().splitlines()
    assert len(lines) == 59  # one a second, from 1 s; the last reading is at 59.9 s
    pattern = (r"Stats \d+\.\d: extruder: target=200 temp=\d+\.\d pwm=\d\.\d{3} "
               r"heater_bed: target=60 temp=\d+\.\d pwm=\d\.\d{3} print_time=\d+\.\d{3} buffer_time=0\.000 print_stall=0")
    assert all(re.fullmatch(pattern, line) for line in lines), lines[0]


def test_bad_scenario_file_gets_a_message_naming_file_and_field(capsys, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('duration_s = 100\n[[setpoint]]\nat_s = 0\nheater = "hotend"\ntarget_c = "hot"\n')
    code, out, err = run(capsys, "--scenario", str(path), "--no-plot", "--out", str(tmp_path))
    assert code == 2
    assert "bad.toml" in err and "setpoint[0].target_c" in err
    assert "Traceback" not in err


def test_unknown_plant_parameter_is_named(capsys, tmp_path):
    code, _, err = run(capsys, "--set", "powr_w=50", "--no-plot", "--out", str(tmp_path))
    assert code == 2 and "powr_w" in err


def test_malformed_set_option(capsys, tmp_path):
    code, _, err = run(capsys, "--set", "power_w", "--no-plot", "--out", str(tmp_path))
    assert code == 2 and "--set 'power_w': expected KEY=VALUE" in err


def test_help_lists_firmwares_plants_and_scenarios(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for word in ("fuzzy_pi", "bangbang", "seed001_fopdt", "thermistor_falls_out", "--engine", "--noise"):
        assert word in out
