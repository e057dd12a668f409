"""docs/klipper.md's shell blocks run as the doc writes them, and print what it says they print.

Each ```sh block runs as one bash script from the repository's root, with:
- ``XDG_RUNTIME_DIR`` the test's own folder (the doc's ``$RUN`` lives there: parallel runs do not collide);
- ``.venv-klippy/bin/`` klippy's venv ($HEATER_TWIN_KLIPPY_VENV), ``.venv/bin/python`` the interpreter
  running the tests, and its bin folder first on PATH (twin-klipper-mcu);
- a trap that stops the block's background jobs (the MCU, klippy) when it ends.
A block without a case here fails, and so does a case whose block left the doc."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_port.thermistor import KLIPPER_SENSORS
from tests.conftest import unavailable
from tools.klipper_host.session import KLIPPY_VENV_ENV, Missing, faketime_env, venv_command
from twin.klipper_twin import calc_temp

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "klipper.md"
BLOCK_TIMEOUT_S = 900  # hang guard of one block on a loaded machine
AMBIENT_C = calc_temp(KLIPPER_SENSORS["EPCOS 100K B57560G104F"], 4700.0, 8 * 978 / (8 * 1023))  # 25 C, as klippy reads it
# each block, by its last line, and a check of what the block printed
CASES = {
    """.venv/bin/python -m tools.klipper_host.api "$RUN/klippy.sock" $'TEMPERATURE_WAIT SENSOR=heater_bed"""
    """ MINIMUM=20\\nM105'""":
        lambda out: out.splitlines()[-1] == f"B:{AMBIENT_C:.1f} /0.0 T0:{AMBIENT_C:.1f} /0.0",
    '.venv/bin/python -m tools.klipper_host.api "$RUN/klippy.sock" "PID_CALIBRATE HEATER=hotend TARGET=200"':
        lambda out: "// PID parameters: pid_Kp=" in out and "SAVE_CONFIG" in out,
}


def sh_blocks() -> list[str]:
    return re.findall(r"```sh\n(.*?)```", DOC.read_text(), flags=re.S)


def test_every_block_has_a_case_and_every_case_a_block():
    assert sorted(block.strip().splitlines()[-1] for block in sh_blocks()) == sorted(CASES)


@pytest.mark.parametrize("block", sh_blocks(), ids=lambda block: block.strip().splitlines()[-1].split()[-2])
def test_the_block_runs_as_written(block, tmp_path):
    try:
        klippy_bin = venv_command(KLIPPY_VENV_ENV).parent
        faketime_env(10)
    except Missing as exc:
        unavailable(str(exc))
    script = block.replace(".venv-klippy/bin/", f"{klippy_bin}/").replace(".venv/bin/python", sys.executable)
    env = {"PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin", "HOME": str(tmp_path), "USER": "doc",
           "XDG_RUNTIME_DIR": str(tmp_path)}
    done = subprocess.run(["bash", "-c", "set -e\ntrap 'kill $(jobs -p) 2>/dev/null; wait' EXIT\n" + script],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=BLOCK_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    assert CASES[block.strip().splitlines()[-1]](done.stdout), done.stdout
