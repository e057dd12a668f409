"""twin-klipper-mcu's command line: the printed config, and one-line errors on bad input."""

from __future__ import annotations

import subprocess
import sys

import pytest

from protocol.klipper_mcu.printer_cfg import CONFIG_END
from tests.helpers.serial_host import ROOT, START_TIMEOUT_S

CLI = [sys.executable, "-m", "tools.cli.klipper_mcu"]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, cwd=ROOT, timeout=START_TIMEOUT_S)


def test_print_config_matches_the_board():
    done = run("--print-config", "--link", "/tmp/x-mcu", "--no-bed", "--sensor-type", "Generic 3950")
    assert done.returncode == 0
    lines = done.stdout.splitlines()
    assert lines[-1] == CONFIG_END
    assert {"serial: /tmp/x-mcu", "heater_pin: PB4", "sensor_pin: PK5", "sensor_type: Generic 3950",
            "[heater_generic hotend]", "kinematics: none", "restart_method: command"} <= set(lines)
    assert "[heater_bed]" not in lines


@pytest.mark.parametrize(("args", "message"), [
    (("--speed", "0"), "argument --speed: 0 x real time is outside 0.01..50 x real time"),
    (("--scenario", "no_such"), "no_such: neither a preset name nor an existing scenario file"),
    (("--sensor-type", "PT100"), "argument --sensor-type: invalid choice: 'PT100'"),
])
def test_bad_input_is_one_line(args, message):
    done = run(*args, "--print-config")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
