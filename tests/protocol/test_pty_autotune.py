"""pyserial on twin-serial's pty: M303 E0 S210 C8 U1 at --speed max returns Marlin's whole
autotune report, its gains follow from the last Ku and Tu it printed, and U1 applied them.
Every read has a deadline and the port and the process are closed whatever happens.
"""

from __future__ import annotations

import re

import pytest
import serial
from tests.helpers.serial_host import READ_TIMEOUT_S, expect, twin_serial

M303_DEADLINE_S = 600  # a hang guard: well under 2 s on an idle machine (python -m tools.bench protocol)
PRINTED = 0.005  # Marlin prints these floats with 2 decimals
BIAS = re.compile(r"^ bias: \d+ d: \d+ min: \d+\.\d\d max: \d+\.\d\d")
KU_TU = re.compile(r"Ku: (\d+\.\d\d) Tu: (\d+\.\d\d)$")
GAINS = re.compile(r"^ Kp: (\d+\.\d\d) Ki: (\d+\.\d\d) Kd: (\d+\.\d\d)$")
DEFINE = re.compile(r"^#define DEFAULT_K([pid]) (\d+\.\d\d)$")
M301 = re.compile(r"^echo:  M301 P(\d+\.\d\d) I(\d+\.\d\d) D(\d+\.\d\d)$")


def classic_pid_bounds(ku: float, tu: float) -> list[tuple[float, float]]:
    """The (low, high) range of Kp, Ki, Kd from Ku and Tu known to print precision:
    Kp = 0.6 Ku, Ki = 2 Kp / Tu, Kd = Kp Tu / 8, each printed to 2 decimals itself."""
    kp = (0.6 * (ku - PRINTED), 0.6 * (ku + PRINTED))
    tu_range = (tu - PRINTED, tu + PRINTED)
    ki = (2 * kp[0] / tu_range[1], 2 * kp[1] / tu_range[0])
    kd = (kp[0] * tu_range[0] / 8, kp[1] * tu_range[1] / 8)
    return [(low - PRINTED, high + PRINTED) for low, high in (kp, ki, kd)]


@pytest.mark.slow


def test_m303_over_a_pty_reports_and_applies_classic_pid(tmp_path):
    with (twin_serial("--speed", "max", tmp_path=tmp_path) as (_, path),
          serial.Serial(path, 115200, timeout=READ_TIMEOUT_S) as port):
        expect(port, "^echo:  M304 ")  # the banner's last line
        port.write(b"M303 E0 S210 C8 U1\n")
        lines = expect(port, "^ok$", timeout_s=M303_DEADLINE_S)
        port.write(b"M301\n")
        reported = expect(port, "^ok$")

    assert lines[0] == "PID Autotune start"
    assert sum(bool(BIAS.match(line)) for line in lines) >= 3
    ku_tu = [(float(m[1]), float(m[2])) for line in lines if (m := KU_TU.search(line))]
    gains = [m.groups() for line in lines if (m := GAINS.match(line))]
    assert len(ku_tu) == len(gains) == lines.count(" Classic PID ") >= 1
    assert lines[-5] == ("PID Autotune finished! Put the last Kp, Ki and Kd constants from below "
                         "into Configuration.h")
    defines = [DEFINE.match(line) for line in lines[-4:-1]]
    assert [m[1] for m in defines] == ["p", "i", "d"]
    final = tuple(m[2] for m in defines)
    assert final == gains[-1]  # the last gains printed are the ones to put in Configuration.h

    for value, (low, high) in zip(map(float, final), classic_pid_bounds(*ku_tu[-1]), strict=True):
        assert low <= value <= high

    applied = M301.match(reported[0])  # U1: M301 now reports exactly those gains
    assert applied is not None and applied.groups() == final
