"""Start-up imports only what the command needs: ``--help`` loads none of the heavy libraries (numba, scipy,
matplotlib, dask), whose import costs seconds of CPU on a busy machine. Checked on the modules a fresh
interpreter holds after ``--help`` (what it imported, not how long it took: timing is tools.bench startup's)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("numba", "scipy", "matplotlib", "dask")
LIGHT = ["tools.cli.sim", "tools.cli.serial", "tools.cli.klipper_mcu", "tools.cli.fit", "tools.cli.compare",
         "tools.cli.firmware_report", "tools.seeds", "tools.bench", "tools.cli.tune"]
HELP = """
import json, runpy, sys
sys.argv = [{module!r}, "--help"]
try:
    runpy.run_module({module!r}, run_name="__main__", alter_sys=True)
except SystemExit as exc:
    status = exc.code
print(json.dumps({{"status": status, "loaded": sorted(m for m in sys.modules if m.split(".")[0] in {heavy!r})}}))
"""


def _help_imports(module: str) -> dict:
    done = subprocess.run([sys.executable, "-c", HELP.format(module=module, heavy=HEAVY)], capture_output=True,
                          text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("module", LIGHT)
def test_help_imports_no_heavy_library(module):
    result = _help_imports(module)
    assert result["status"] in (0, None)
    assert result["loaded"] == []


def test_the_check_sees_a_heavy_import():
    loaded = _help_imports("tools.validation.plant_check")  # a python -m command whose module imports scipy at the top
    assert "scipy" in loaded["loaded"]


def test_the_seed_ids_name_every_seed_module():
    from tools.seeds.papers import PAPERS, SEED_IDS

    files = sorted(p.stem.removeprefix("seed") for p in (ROOT / "tools" / "seeds").glob("seed[0-9][0-9][0-9].py"))
    assert list(SEED_IDS) == files
    assert all(callable(PAPERS[seed].report) and callable(PAPERS[seed].steps) for seed in SEED_IDS)
