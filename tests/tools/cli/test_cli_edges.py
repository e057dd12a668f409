"""Edges of the command lines: what a killed command printed stays printed; a user's
``--controller module:NAME`` is checked before it is imported and leaves sys.path as it was."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tools.tuning.controllers import resolve_controller
from twin.limits import UserError

ROOT = Path(__file__).resolve().parents[3]
KILLED = """
import os, signal, sys, {module} as command
def run(*args, **kwargs):
    print("first line, printed before the kill")
    os.kill(os.getpid(), signal.SIGKILL)
command.run = run
sys.exit(command.main({argv!r}))
"""


@pytest.mark.parametrize(("module", "argv"), [("tools.cli.fit", ["{log}"]),
                                              ("tools.cli.tune", ["--plant", "hotend_cartridge"])])
def test_a_killed_command_leaves_what_it_printed_on_a_pipe(tmp_path, module, argv):
    log = tmp_path / "log.csv"
    log.write_text("t_s,temp_c,duty\n0,25,1\n1,26,1\n")
    code = KILLED.format(module=module, argv=[arg.format(log=log) for arg in argv])
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == -9, done.stderr  # killed: no exit handler flushed anything
    assert done.stdout == "first line, printed before the kill\n"


def _space_module(folder: Path, name: str) -> None:
    (folder / f"{name}.py").write_text("from firmware_port.marlin.pid import pid_space\n\n\n"
                                       "def space(heater):\n    return pid_space()\n")


def test_a_user_module_is_imported_from_the_current_folder_and_sys_path_stays(tmp_path, monkeypatch):
    _space_module(tmp_path, "my_space_module_37")
    monkeypatch.chdir(tmp_path)
    before = list(sys.path)
    space = resolve_controller("my_space_module_37:space", "hotend")
    assert [p.name for p in space.params] == ["kp", "ki", "kd"]
    assert sys.path == before


@pytest.mark.parametrize("name", ["..:x", ".x:y", "a b:c", "os.:x", ":x"])
def test_a_module_name_that_is_not_dotted_identifiers_is_one_line(name):
    with pytest.raises(UserError) as error:
        resolve_controller(name, "hotend")
    assert str(error.value).startswith(f"--controller {name}: ") and "\n" not in str(error.value)


def test_a_user_module_that_is_a_fifo_is_not_found_and_nothing_waits(tmp_path, monkeypatch):
    os.mkfifo(tmp_path / "fifo_module_37.py")  # opening it would wait for a writer forever
    monkeypatch.chdir(tmp_path)
    before = list(sys.path)
    with pytest.raises(UserError, match=r"^--controller fifo_module_37:space: no module named 'fifo_module_37'$"):
        resolve_controller("fifo_module_37:space", "hotend")
    assert sys.path == before and "fifo_module_37" not in sys.modules


def test_a_module_built_into_python_is_refused_before_any_import():
    with pytest.raises(UserError, match=r"^--controller sys:path: 'sys' is built into Python, not a module file$"):
        resolve_controller("sys:path", "hotend")


def test_a_missing_package_level_is_named(tmp_path, monkeypatch):
    (tmp_path / "pkg_37").mkdir()
    (tmp_path / "pkg_37" / "__init__.py").write_text("")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserError, match=r"no module named 'pkg_37.inner'$"):
        resolve_controller("pkg_37.inner:space", "hotend")
