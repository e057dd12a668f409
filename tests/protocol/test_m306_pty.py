"""M306 T over a pseudo-terminal, as a host sends it: twin-serial --firmware mpc on the default
``hotend`` preset answers with Marlin's autotune transcript, which must equal the golden file
(tests/golden/m306_autotune.txt, ``python -m tools.validation.golden_m306 --write``) line by line,
exactly: with the host-driven clock (--idle-speed 0) the session is a function of the bytes sent,
and the firmware runs on an integer clock with the float32 law. The constants it prints must be
within 10 % of the plant's own (the ``hotend`` preset is Marlin's MPC model, twin/plants.py).
The wall time is measured and printed (-s shows it), never asserted.
"""

from __future__ import annotations

import re
import time

import pytest
import serial

from tests.helpers.serial_host import START_TIMEOUT_S, expect, twin_serial
from tools.validation.golden_m306 import COMMAND, GOLDEN_M306_PATH, PLANT_PRESET
from twin.plants import (
    MPC_AMBIENT_XFER_FAN255_W_K,
    MPC_AMBIENT_XFER_W_K,
    MPC_BLOCK_HEAT_CAPACITY_J_K,
    MPC_SENSOR_RESPONSIVENESS_PER_S,
)

DEADLINE_S = 600  # a hang guard for the whole autotune; it takes about a second on an idle machine
FINISHED = "MPC Autotune finished! Put the constants below into Configuration.h"
PLANT = {  # what the four lines name, and the plant's value of each
    "MPC_BLOCK_HEAT_CAPACITY": MPC_BLOCK_HEAT_CAPACITY_J_K,
    "MPC_SENSOR_RESPONSIVENESS": MPC_SENSOR_RESPONSIVENESS_PER_S,
    "MPC_AMBIENT_XFER_COEFF": MPC_AMBIENT_XFER_W_K,
    "MPC_AMBIENT_XFER_COEFF_FAN255": MPC_AMBIENT_XFER_FAN255_W_K,
}
# Marlin's method is approximate (the sensor's lag read from one sample, A and F from 20 s windows
# whose stored-heat term sees the reading step one ADC count): the bound, 10 %.
TOLERANCE = 0.10


@pytest.fixture
def mpc_port(tmp_path):
    """twin-serial --firmware mpc --plant hotend on a pty, host-driven while idle; the port, closed whatever happens."""
    with twin_serial("--firmware", "mpc", "--plant", PLANT_PRESET, "--speed", "max", "--idle-speed", "0",
                     tmp_path=tmp_path) as (_, path):
        with serial.Serial(path, 115200, timeout=1) as port:
            yield port


@pytest.mark.slow  # a process start and the tune: about 6 s on a loaded machine
def test_m306_t_over_a_pty_matches_the_golden_transcript(mpc_port):
    expect(mpc_port, r"^echo:  M306 E0 ", START_TIMEOUT_S)  # the banner's last line: the settings report
    start_s = time.monotonic()
    mpc_port.write(COMMAND.encode() + b"\n")
    got = expect(mpc_port, r"^ok$", DEADLINE_S)
    print(f"\nM306 T over the pty: {time.monotonic() - start_s:.2f} s wall, {len(got)} lines")

    expected = GOLDEN_M306_PATH.read_text().splitlines()
    for number, (want, have) in enumerate(zip(expected, got), start=1):
        assert have == want, f"line {number} differs (regenerate only on purpose: python -m tools.validation.golden_m306 --write)"
    assert len(got) == len(expected)

    assert got[-6] == FINISHED
    found = dict(line.rsplit(" ", 1) for line in got[-5:-1])
    assert list(found) == list(PLANT)
    for name, plant_value in PLANT.items():
        assert abs(float(found[name]) - plant_value) <= TOLERANCE * plant_value, (name, found[name], plant_value)


def test_the_golden_transcript_is_marlins_sequence():
    lines = GOLDEN_M306_PATH.read_text().splitlines()
    assert lines[:2] == ["MPC Autotune start for E0", "Cooling to ambient"]
    phases = [line for line in lines if not line.startswith(" T:")]
    assert phases[2] == "Heating to over 200C"
    assert re.fullmatch(r"Measuring ambient heatloss at \d+\.\d\d", phases[3])
    assert phases[4:] == [FINISHED, *(f"{name} {line.rsplit(' ', 1)[1]}" for name, line in zip(PLANT, phases[5:9])),
                          "ok"]
    reports = [line for line in lines if line.startswith(" T:")]
    assert all(re.fullmatch(r" T:\d+\.\d\d /\d+\.00 B:\d+\.\d\d /0\.00 @:\d+ B@:0", line) for line in reports)
    assert any("/200.00" in line and line.endswith("@:127 B@:0") for line in reports)  # full power, target shown 200
    # one report a second: cooling from ambient is one 10 s test, the heat-up and the 4 x 20 s of holding follow
    assert 150 < len(reports) < 300
