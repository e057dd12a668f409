"""A bug is never dressed as bad input: a fault injected into each command (a ValueError, the type that used to
mean "bad input") gives one stderr line that says "internal error" and names the file holding the traceback,
and exit status 70 (EX_SOFTWARE). The fault is injected in a subprocess that patches the command's work
function, then calls its main as the console script does."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tools.entry import EXIT_INTERNAL, EXIT_USAGE

ROOT = Path(__file__).resolve().parents[3]
# (command, its module, the function main runs under run_main, argv that reaches it)
COMMANDS = [
    ("twin-sim", "tools.cli.sim", "run", ["--out", "{tmp}/out"]),
    ("twin-serial", "tools.cli.serial", "run", []),
    ("twin-klipper-mcu", "tools.cli.klipper_mcu", "run", []),
    ("twin-fit", "tools.cli.fit", "run", ["{tmp}/log.csv"]),
    ("twin-compare", "tools.cli.compare", "run", ["{tmp}/log.csv"]),
    ("twin-tune", "tools.cli.tune", "run", ["--plant", "hotend_cartridge"]),
    ("twin-firmware-report", "tools.cli.firmware_report", "run", []),
    ("python -m tools.bench", "tools.bench", "run", ["twin"]),
    ("tools.seeds", "tools.seeds.__main__", "_page", ["--out", "{tmp}/page.md"]),
]
INJECT = """
import sys, {module} as command
def fault(*args, **kwargs):
    raise ValueError("injected fault 1234")
command.{function} = fault
sys.exit(command.main({argv!r}))
"""


@pytest.mark.parametrize(("prog", "module", "function", "argv"), COMMANDS, ids=[c[1] for c in COMMANDS])
def test_an_internal_fault_says_so_and_where_its_traceback_is(tmp_path, prog, module, function, argv):
    (tmp_path / "log.csv").write_text("t_s,temp_c,duty\n0,25,1\n1,26,1\n")
    argv = [arg.format(tmp=tmp_path) for arg in argv]
    state = tmp_path / "state"
    code = INJECT.format(module=module, function=function, argv=argv)
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "XDG_STATE_HOME": str(state)})
    assert done.returncode == EXIT_INTERNAL != EXIT_USAGE, (done.returncode, done.stderr)
    assert done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith(f"{prog}: internal error: ValueError: injected fault 1234; the traceback is in "), \
        done.stderr
    assert "please report it" in done.stderr and "Traceback" not in done.stderr
    path = Path(re.search(r"the traceback is in (\S+);", done.stderr).group(1))
    assert path.parent == state / "heater-twin" and path.name.startswith(prog.split()[-1] + "-")
    text = path.read_text()
    assert text.startswith("Traceback (most recent call last):") and "ValueError: injected fault 1234" in text
    assert "in fault" in text  # the frame that raised it


def test_without_a_state_folder_the_traceback_goes_to_the_temporary_folder(tmp_path):
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("")  # a file where the state folder would be: mkdir fails
    code = INJECT.format(module="tools.cli.firmware_report", function="run", argv=[])
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "XDG_STATE_HOME": str(blocked),
                               "TMPDIR": str(tmp_path)})
    assert done.returncode == EXIT_INTERNAL, done.stderr
    path = Path(re.search(r"the traceback is in (\S+);", done.stderr).group(1))
    assert path.parent == tmp_path and "injected fault 1234" in path.read_text()
