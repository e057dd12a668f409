"""twin-tune --loop kalico: Kalico's PID tuned against its PID_CALIBRATE and printed as the [extruder] section
Kalico saves, Kalico's MPC against its MPC_CALIBRATE, and the two compared on the same plant."""

from __future__ import annotations

import re

import pytest

from tools.cli.tune import main

ANSWER = re.compile(r"^answer: (?:new gains \((\S+)\)|keep )", re.M)
SECTION = re.compile(r"^Kalico printer\.cfg \(proven on the Kalico loop\):\n  \[extruder\]\n((?:  \S+: .*\n)+)", re.M)


def _options(block: str) -> dict[str, str]:
    return dict(line.strip().split(": ", 1) for line in block.splitlines())


@pytest.mark.slow  # 5.6 s of CPU: a tune and its proof
def test_kalico_pid_is_tuned_proven_and_printed_as_kalicos_section(capsys):
    status = main(["--plant", "hotend", "--loop", "kalico", "--budget", "90", "--proof", "2", "--plot", "none",
                   "--progress", "lines"])
    out = capsys.readouterr().out
    assert status in (0, 1)
    assert "loop kalico" in out and re.search(r"^to beat: PID_CALIBRATE  Kp", out, re.M), out
    answer = ANSWER.search(out)
    assert answer is not None and answer.group(1) is not None, out  # seed 0 beats Kalico's PID_CALIBRATE
    section = SECTION.search(out)
    assert section is not None, out
    options = _options(section.group(1))
    assert options["control"] == "pid" and options["pid_version"] == "1"
    row = re.search(rf"^ \*{re.escape(answer.group(1))}\s+Kp (\S+) Ki (\S+) Kd (\S+)", out, re.M)
    assert row is not None, out
    for key, shown in zip(("pid_kp", "pid_ki", "pid_kd"), row.groups()):
        assert float(options[key]) == pytest.approx(float(shown), rel=1e-3)  # the section holds the answer's gains


@pytest.mark.slow  # 13.6 s of CPU: two tunes and their proofs
def test_pid_and_mpc_are_compared_on_the_kalico_loop(capsys):
    assert main(["--plant", "hotend", "--controller", "pid,mpc", "--loop", "kalico", "--method", "rules",
                 "--spread", "0", "--proof", "2", "--plot", "none", "--progress", "lines"]) == 0
    out = capsys.readouterr().out
    assert "controller kalico_mpc, objective heater, loop kalico" in out
    assert re.search(r"^to beat: MPC_CALIBRATE  block_heat_capacity \S+ J/K", out, re.M), out
    comparison = out[out.index("comparison on the same plant"):].splitlines()
    assert [line.split()[:2] for line in comparison[1:]] == [["pid", "(kalico)"], ["kalico_mpc", "(kalico)"]]
    assert all(re.search(r"0 trips of 2, overshoot worst \S+ C", line) for line in comparison[1:]), comparison


@pytest.mark.slow  # 9.9 s of CPU: a tune and its proof
def test_an_unproven_kalico_mpc_prints_its_mpc_section(capsys):
    assert main(["--plant", "hotend", "--controller", "mpc", "--loop", "kalico", "--method", "rules",
                 "--spread", "0", "--proof", "0", "--plot", "none", "--progress", "lines"]) == 0
    out = capsys.readouterr().out
    block = re.search(r"^Kalico printer\.cfg \(UNPROVEN, from the Kalico loop\):\n  \[extruder\]\n((?:  \S+: .*\n)+)",
                      out, re.M)
    assert block is not None, out
    options = _options(block.group(1))
    assert options["control"] == "mpc" and options["heater_power"] == "40" and options["cooling_fan"] == "fan"
    ambient, full_fan = (float(v) for v in options["fan_ambient_transfer"].split(", "))
    assert ambient == float(options["ambient_transfer"]) and full_fan > ambient  # the part fan draws heat
    assert float(options["block_heat_capacity"]) > 0 and float(options["sensor_responsiveness"]) > 0


def test_kalicos_mpc_on_another_loop_is_one_line(capsys):
    assert main(["--plant", "hotend", "--controller", "kalico_mpc", "--loop", "marlin"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "twin-tune: error: --loop marlin: controller kalico_mpc is Kalico's MPC: it runs on the kalico " \
                  "loop only", err
