"""twin-sim end to end: defaults, each firmware, outputs, and clear errors on bad input."""

import re

import pytest

from tools.cli.sim import main


def run(capsys, *argv):
    try:
        code = main(list(argv))
    except SystemExit as exc:  # a flag argparse refuses
        code = exc.code
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
    assert len(re.findall(r"^limit_cycle_amplitude_c\s+-$", out, re.M)) == 2  # hotend and bed hold
    assert "limit cycle" not in out
    csv = (tmp_path / "heat_hold_pid.csv").read_text()
    assert csv.startswith("t_s,hotend_target_c,hotend_measured_c,")
    assert len(csv.splitlines()) > 3600  # one row per 0.164 s reading
    png = (tmp_path / "heat_hold_pid.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("firmware", ["pid", "pid_float", "bangbang", "fuzzy_pi"])
def test_each_firmware_reaches_the_target(capsys, tmp_path, firmware):
    """Each holds the target; bang-bang (no hysteresis, full power or off) by a limit cycle, reported as one."""
    code, out, err = run(capsys, "--firmware", firmware, "--duration", "200", "--no-bed", "--no-plot",
                         "--out", str(tmp_path))
    assert code == 0, err
    assert re.search(r"^reached\s+yes$", out, re.M)
    steady = re.search(r"^steady_state_error_c\s+(\S+)$", out, re.M).group(1)
    amplitude = re.search(r"^limit_cycle_amplitude_c\s+(\S+)$", out, re.M).group(1)
    if firmware == "bangbang":
        assert steady == "-" and 1.0 < float(amplitude) < 10.0
    else:
        assert abs(float(steady)) < 3.0 and amplitude == "-"


def test_a_limit_cycle_is_reported_with_its_amplitude_and_period(capsys, tmp_path):
    """The Marlin default gains on the 60 W cartridge at 240 C cycle +-10 C every ~80 s once at the target:
    said so, and no steady-state error (it never settles), where it used to read 'steady_state_error 5.03'."""
    code, out, err = run(capsys, "--plant", "hotend_cartridge", "--target", "240", "--duration", "300", "--no-bed",
                         "--no-plot", "--out", str(tmp_path))
    assert code == 0, err
    assert re.search(r"^reached\s+yes$", out, re.M) and re.search(r"^steady_state_error_c\s+-$", out, re.M)
    amplitude = float(re.search(r"^limit_cycle_amplitude_c\s+(\S+)$", out, re.M).group(1))
    period = float(re.search(r"^limit_cycle_period_s\s+(\S+)$", out, re.M).group(1))
    assert 8.0 < amplitude < 13.0 and 65.0 < period < 95.0
    line = re.search(r"^hotend step 1: limit cycle in the hold, \+-(\S+) C every (\S+) s: it never settles", out, re.M)
    assert line and float(line[1]) == amplitude and float(line[2]) == pytest.approx(period, abs=0.06)


def test_a_noisy_stable_hold_is_no_limit_cycle(capsys, tmp_path):
    """The default hotend with 3 LSB of ADC noise holds 210 C: no limit cycle, a steady-state error."""
    code, out, err = run(capsys, "--noise", "3", "--no-bed", "--no-plot", "--out", str(tmp_path))
    assert code == 0, err
    assert re.search(r"^limit_cycle_amplitude_c\s+-$", out, re.M) and "limit cycle" not in out
    assert abs(float(re.search(r"^steady_state_error_c\s+(\S+)$", out, re.M).group(1))) < 0.5


def test_protection_trip_is_reported_and_exits_1(capsys, tmp_path):
    """A script can tell a halt from a pass: exit status 1 (--help lists the statuses)."""
    code, out, _ = run(capsys, "--scenario", "cartridge_falls_out", "--no-plot", "--out", str(tmp_path))
    assert code == 1
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


def test_gains_flags_set_the_pid_at_zero_and_are_printed(capsys, tmp_path):
    code, out, err = run(capsys, "--gains", "12.6,0.39,103", "--bed-gains", "50,1.5,400", "--duration", "30",
                         "--no-plot", "--out", str(tmp_path))
    assert code == 0, err
    assert "gains: hotend Kp 12.6 Ki 0.39 Kd 103; bed Kp 50 Ki 1.5 Kd 400\n" in out


def test_default_gains_are_printed(capsys, tmp_path):
    code, out, _ = run(capsys, "--duration", "5", "--no-plot", "--out", str(tmp_path))
    # the stock build's own M303 results (firmware_port/firmwares.py STOCK_HOTEND_GAINS, STOCK_BED_GAINS)
    assert code == 0 and "gains: hotend Kp 19.96 Ki 2.06 Kd 48.23; bed Kp 86.92 Ki 10.4 Kd 484.2\n" in out


def test_scenario_pid_timeline_changes_gains_like_m301(capsys, tmp_path):
    """A [[pid]] entry later in the run is M301 in the timeline: the run differs from then on only."""
    text = ('duration_s = 200\n[[setpoint]]\nat_s = 0\nheater = "hotend"\ntarget_c = 200\n'
            '[[pid]]\nat_s = 150\nheater = "hotend"\nkp = 12\nki = 1\nkd = 30\n')
    path = tmp_path / "gains.toml"
    path.write_text(text)
    csvs = []
    for scenario in (str(path), None):
        args = ["--no-bed", "--no-plot", "--out", str(tmp_path), "--csv", str(tmp_path / f"{len(csvs)}.csv")]
        args += ["--scenario", scenario] if scenario else ["--duration", "200", "--target", "200"]
        assert run(capsys, *args)[0] == 0
        csvs.append((tmp_path / f"{len(csvs)}.csv").read_text().splitlines())
    first_diff = next(i for i, (a, b) in enumerate(zip(*csvs, strict=False)) if a != b)
    assert float(csvs[0][first_diff].split(",")[0]) >= 150.0


@pytest.mark.parametrize(("argv", "message"), [
    (["--gains", "1,2"], "--gains '1,2': expected three numbers KP,KI,KD"),
    (["--gains", "2000,1,1"], "gains.hotend.kp: must be in 0..1000"),
    (["--gains", "1,2,3", "--firmware", "bangbang"], "firmware 'bangbang' has no PID on that heater"),
    (["--duration", "1e300"], "argument --duration: 1e+300 s is outside 0.001024..4.29497e+06 s"),
    (["--set", "power_w=1e308"], "plant parameter power_w=1e+308: beyond"),
    (["--noise", "nan"], "argument --noise: expected a finite number, not 'nan'"),
    (["--plot", "x.svg"], "the plot is written as PNG"),
])
def test_impossible_values_get_one_line_naming_the_field(capsys, tmp_path, argv, message):
    code, out, err = run(capsys, *argv, "--out", str(tmp_path))
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())  # refused before any work or output


def test_unwritable_output_is_refused_before_the_run(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, out, err = run(capsys, "--out", str(blocker / "sub"))
    assert code == 2 and "cannot create the output folder" in err and out == ""


def test_a_clamped_target_is_said(capsys, tmp_path):
    code, out, _ = run(capsys, "--target", "300", "--duration", "5", "--no-plot", "--no-bed", "--out", str(tmp_path))
    assert code == 0
    assert "note: hotend target 300 C at 0 s is clamped to 260 C by the firmware" in out


def test_record_every_bounds_the_trace_and_keeps_the_run(capsys, tmp_path):
    """A long run's trace is bounded by --record-every; the firmware's run itself is unchanged."""
    rows = {}
    for every in ("0", "10"):
        csv = tmp_path / f"{every}.csv"
        code, out, err = run(capsys, "--duration", "300", "--no-plot", "--no-bed", "--record-every", every,
                             "--csv", str(csv), "--out", str(tmp_path))
        assert code == 0, err
        rows[every] = [line.split(",") for line in csv.read_text().splitlines()[1:] if not line.startswith("#")]
    assert len(rows["0"]) > 1800 and len(rows["10"]) <= 31
    t_s = [float(r[0]) for r in rows["10"]]
    assert all(9.9 < b - a < 10.2 for a, b in zip(t_s, t_s[1:]))
    full = {r[0]: r for r in rows["0"]}
    assert all(full[r[0]] == r for r in rows["10"])  # the kept rows are the full run's rows


def test_record_every_is_checked(capsys, tmp_path):
    code, _, err = run(capsys, "--record-every", "nan", "--out", str(tmp_path))
    assert code == 2 and "argument --record-every: expected a finite number, not 'nan'" in err


def test_output_names_say_the_plant_and_gains_so_runs_do_not_overwrite_each_other(capsys, tmp_path):
    common = ("--duration", "5", "--no-plot", "--out", str(tmp_path))
    assert run(capsys, *common)[0] == 0
    assert run(capsys, "--plant", "hotend_cartridge", "--gains", "12.6,0.39,103", *common)[0] == 0
    assert run(capsys, "--no-bed", "--set", "power_w=50", *common)[0] == 0
    assert sorted(path.name for path in tmp_path.iterdir()) == [
        "heat_hold_pid.csv",  # the defaults keep the README's name
        "heat_hold_pid_hotend_cartridge_gains-12.6-0.39-103.csv",
        "heat_hold_pid_nobed_power_w-50.csv",
    ]


@pytest.mark.parametrize("option", ["--plot", "--csv", "--klipper-log"])
def test_a_missing_output_folder_is_refused_as_twin_compare_refuses_it(capsys, tmp_path, option):
    path = tmp_path / "missing" / ("x.png" if option == "--plot" else "x.txt")
    code, out, err = run(capsys, option, str(path), "--out", str(tmp_path))
    assert code == 2 and out == ""
    assert err == f"twin-sim: error: {option} {str(path)!r}: the folder {str(path.parent)!r} does not exist\n"
    assert not path.parent.exists()


@pytest.mark.slow


def test_progress_goes_to_a_terminal_only(tmp_path):
    """tqdm on stderr when it is a terminal; nothing when it is a file or a pipe."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import sys
    import termios

    args = [sys.executable, "-m", "tools.cli.sim", "--duration", "60", "--no-plot", "--out", str(tmp_path)]
    piped = subprocess.run(args, capture_output=True, text=True, timeout=1800)
    assert piped.returncode == 0 and piped.stderr == ""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))  # a terminal has a size
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    shown = b""
    try:
        while True:  # read while it runs: a closed terminal's unread output is lost
            try:
                chunk = os.read(master, 4096)
            except OSError:  # EIO: the program has exited and closed the terminal
                break
            if not chunk:
                break
            shown += chunk
    finally:
        os.close(master)
        assert proc.wait(timeout=1800) == 0
    assert b"60/60 s virtual" in shown


@pytest.mark.parametrize(("engine", "said"), [("reference", "the tick-by-tick reference engine"),
                                              ("avr", "the controllers' C compiled for the ATmega328P")])
def test_a_non_default_engine_is_said_and_in_the_file_names(capsys, tmp_path, engine, said, request):
    """--engine avr ran on simavr without saying so, and wrote over the fast engine's files."""
    if engine == "avr":
        request.getfixturevalue("avr_toolchain")
    code, out, err = run(capsys, "--engine", engine, "--duration", "2", "--no-bed", "--out", str(tmp_path))
    assert code == 0, err
    assert out.startswith(f"twin-sim: heat_hold, firmware pid, 2 s virtual, seed 0, engine {engine} ({said}")
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"heat_hold_pid_{engine}_nobed.{kind}" for kind in ("csv", "png")]
