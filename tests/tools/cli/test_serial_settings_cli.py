"""twin-serial checks --settings before it serves: one line, exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.slow


def test_an_unwritable_settings_path_is_a_usage_error():
    proc = subprocess.run([sys.executable, "-m", "tools.cli.serial", "--settings", "/proc/x.json"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == "twin-serial: error: settings file /proc/x.json: cannot be written (No such file or directory)\n"
