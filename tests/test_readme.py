"""Every command the README shows runs as written and does what the README says of it.

A command is a line of a ```sh block (its ``# comment`` dropped) or an inline code span that starts with a
program: a console script of pyproject.toml, ``python``, ``python3``, ``pip`` or ``.venv/bin/...``. Each has a
case in CASES; a README command without one fails, and so does a case whose command left the README.

Each runs in bash in the test's own folder, with the interpreter's bin folder first on PATH (the venv the
tests run in, where ``pip install -e`` put the console scripts), as written except for:
- a user's files, ``my_m303.txt`` and ``klippy.log``: a capture of the same kind from the hardware logs;
- ``/tmp/printer`` and ``/tmp/twin-mcu``: paths in the test's folder, so that parallel runs do not collide;
- ``.venv/bin/``: the bin folder of the interpreter running the tests;
- a command whose full run costs minutes (a tune, a seed paper) gets the cheaper flags the README itself
  shows for it (CHEAPER), and only those.
The Quick start's install steps are .ci/run's (CI runs them from scratch): they are compared with it, not
run; its test command is .ci/run's without the slow tests, compared likewise. tests/twin/test_api.py runs
the README's Python block.
"""

from __future__ import annotations

import os
import re
import resource
import select
import shlex
import subprocess
import sys
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
import serial

from protocol.klipper_mcu.printer_cfg import CONFIG_END
from tests.helpers.serial_host import START_TIMEOUT_S, expect
from tools.tuning.answer import CANNOT_MODEL

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CI_RUN = ROOT / ".ci" / "run"
BIN = Path(sys.executable).parent
SCRIPTS = tuple(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"])
PROGRAMS = (*SCRIPTS, "python", "python3", "pip")
# A command is bounded by what it does, not by the wall clock: CPU_LIMIT_S of CPU time per process (a busy
# machine slows the wall clock, not the CPU a command needs; the costliest case, a tune at CHEAPER's budget,
# needs well under a minute), and RUN_TIMEOUT_S of wall time only against a hang (a process that waits).
CPU_LIMIT_S = 600
RUN_TIMEOUT_S = 3600
M303_TIMEOUT_S = 600  # M303 E0 S210 C8 on the default clock: a second or so of wall time when quiet
M303_CAPTURE = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"  # a hotend's M303 with its trace
KLIPPY_CAPTURE = "klippy_stats_icodextrin_ender5_creality427.csv"  # a klippy.log's Stats lines
USER_FILES = {"my_m303.txt": M303_CAPTURE, "klippy.log": KLIPPY_CAPTURE}
PORTS = ("/tmp/printer", "/tmp/twin-mcu")
CHEAP_FLAGS = {"--budget", "--proof"}  # what CHEAPER may add: less search, fewer proof seeds, nothing else


# -- the README's commands ------------------------------------------------------------------------
def _sh_lines(text: str) -> list[str]:
    lines = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        lines += [re.sub(r"\s+#.*$", "", line).strip() for line in block.splitlines()]
    return [line for line in lines if line]


def _inline_commands(text: str) -> list[str]:
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    spans = re.findall(r"(?<!`)`([^`\n]+)`(?!`)", prose)
    return [span for span in spans if span.split()[0] in PROGRAMS or span.startswith(".venv/bin/")]


def readme_commands(text: str) -> list[str]:
    """The README's commands in order, each once."""
    return list(dict.fromkeys(_sh_lines(text) + _inline_commands(text)))


def test_the_commands_are_found_in_blocks_and_prose():
    text = ("```sh\ntwin-sim --a     # why\n\ntwin-serial\n```\nsee `twin-tune --help`, `M303 E0` and `python -m x`"
            "\n```python\nprint(1)\n```\n")
    assert readme_commands(text) == ["twin-sim --a", "twin-serial", "twin-tune --help", "python -m x"]


# -- running one ----------------------------------------------------------------------------------
def as_run(command: str, folder: Path, logs: Path | None) -> str:
    """The command as the test runs it (the module docstring's substitutions)."""
    for port in PORTS:
        command = command.replace(port, shlex.quote(str(folder / Path(port).name)))
    for name, capture in USER_FILES.items():
        word = re.compile(rf"(?<![\w/.-]){re.escape(name)}(?![\w.])")  # the name alone, not inside a path
        if word.search(command):
            assert logs is not None, f"{command}: the case must ask for the hardware logs"
            command = word.sub(shlex.quote(str(logs / capture)), command)
    return command.replace(".venv/bin/", f"{BIN}/")


def environment() -> dict[str, str]:
    return {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "MPLBACKEND": "Agg"}


def _cpu_limit() -> None:
    """In the command's process (and so in each it starts): at most CPU_LIMIT_S of CPU, then SIGXCPU."""
    resource.setrlimit(resource.RLIMIT_CPU, (CPU_LIMIT_S, CPU_LIMIT_S))


def run(command: str, folder: Path) -> subprocess.CompletedProcess:
    done = subprocess.run(["bash", "-c", command], cwd=folder, env=environment(), capture_output=True, text=True,
                          timeout=RUN_TIMEOUT_S, preexec_fn=_cpu_limit)
    assert "Traceback" not in done.stderr, done.stderr
    return done


def start(spawn, command: str, folder: Path) -> subprocess.Popen:
    """A server: bash replaced by the command (exec), so that stopping it stops the server; its stdout
    unbuffered, for ``read_lines``."""
    return spawn(["bash", "-c", f"exec {command}"], cwd=folder, env=environment(), stdout=subprocess.PIPE,
                 stderr=subprocess.DEVNULL, bufsize=0)


def read_lines(proc: subprocess.Popen, last: str | None = None) -> list[str]:
    """A server's stdout up to the line ``last`` (None: its first line), each chunk within START_TIMEOUT_S."""
    text = b""
    while True:
        lines = text.decode().split("\n")[:-1]  # the complete ones
        if last is None and lines:
            return lines[:1]
        if last in lines:
            return lines[: lines.index(last) + 1]
        ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
        chunk = os.read(proc.stdout.fileno(), 4096) if ready else b""
        assert chunk, f"stdout ended or stayed silent for {START_TIMEOUT_S} s after {text.decode()!r}"
        text += chunk


def png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- the cases ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Command:
    """A README command: as ``written``, as the test runs it (``runs``), in ``folder``; ``spawn`` starts a
    server that is stopped at the test's end (tests/conftest.py)."""

    written: str
    runs: str
    folder: Path
    spawn: Callable[..., subprocess.Popen]


@dataclass(frozen=True)
class Case:
    """How a README command is checked; ``logs``: it reads a user's file (a capture stands in); ``slow``:
    marked slow (over about 5 s on a quiet 2-core machine): every command that simulates, tunes or serves."""

    check: Callable[[Command], None]
    logs: bool = False
    slow: bool = True


def _ci_lines() -> list[str]:
    return [line.strip().replace(" --quiet", "") for line in CI_RUN.read_text().splitlines()]


def _extras(step: str) -> set[str]:
    found = re.search(r"-e '\.\[([\w,]*)\]'", step)
    return set(found.group(1).split(",")) if found else set()


def _without_extras(step: str) -> str:
    return re.sub(r"'\.\[[\w,]*\]'", "'.[...]'", step)


def check_install_and_run(c: Command) -> None:
    """The install steps are CI's (any extra CI adds is named in the README), then the default job runs."""
    *install, job = c.written.split(" && ")
    ci = _ci_lines()
    for step in install:
        if _extras(step):
            ci_step = next(line for line in ci if _extras(line))
            assert _without_extras(step) == _without_extras(ci_step), (step, ci_step)
            assert _extras(step) <= _extras(ci_step), (step, ci_step)
            assert all(f"`{extra}` extra" in README.read_text() for extra in _extras(ci_step) - _extras(step))
        else:
            assert step in ci, f"{step!r} is not in .ci/run"
    done = run(as_run(job, c.folder, None), c.folder)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("twin-sim: heat_hold, firmware pid, 600 s virtual")
    assert "hotend (firmware-measured" in done.stdout and "bed (firmware-measured" in done.stdout
    out = c.folder / "twin-out"
    assert (out / "heat_hold_pid.csv").is_file() and png(out / "heat_hold_pid.png")


def _ci_pytest() -> list[str]:
    """main_job's test command as a user's clone runs it: main_job leaves tests/octoprint_plugin to octoprint_job,
    which runs them in OctoPrint's own venv (a user's clone has them in the one venv)."""
    words = shlex.split(next(line for line in _ci_lines() if " -m pytest" in line))
    if PLUGIN_TESTS_ELSEWHERE in words:
        assert any(" -m pytest" in line and " tests/octoprint_plugin " in f"{line} " and "--ignore" not in line
                   for line in _ci_lines()), "main_job leaves tests/octoprint_plugin out and no other job runs them"
        words.remove(PLUGIN_TESTS_ELSEWHERE)
    return words


PLUGIN_TESTS_ELSEWHERE = "--ignore=tests/octoprint_plugin"


def check_quick_tests(c: Command) -> None:
    """CI's test command with the tests marked slow left out (CI runs them all; this test is among them)."""
    ci = _ci_pytest()
    assert shlex.split(c.written) == ci[:3] + ["-m", "not slow"] + ci[3:]
    markers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["markers"]
    assert any(marker.startswith("slow:") for marker in markers)


def check_ci_tests(c: Command) -> None:
    assert shlex.split(c.written) == _ci_pytest()


def check_help(c: Command) -> None:
    done = run(c.runs, c.folder)
    assert done.returncode == 0 and done.stdout.startswith(f"usage: {c.written.split()[0]} "), done.stdout[:200]


def check_plot(c: Command) -> None:
    """The README's picture, redrawn: the default job's plot, where the command names it."""
    (c.folder / "docs").mkdir()
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("twin-sim: heat_hold, firmware pid, 600 s virtual")
    assert png(c.folder / "docs" / "heat_hold_pid.png")


def check_sim(c: Command) -> None:
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("twin-sim: heat_hold, firmware fuzzy_pi,")
    assert re.search(r"^overshoot_c\s", done.stdout, re.M) and re.search(r"^iae_c_s\s", done.stdout, re.M)
    out = c.folder / "twin-out"
    assert (out / "heat_hold_fuzzy_pi.csv").is_file() and png(out / "heat_hold_fuzzy_pi.png")


def check_serial(c: Command) -> None:
    """A host on the link: M303 E0 S210 C8 autotunes as Marlin does and prints the #define lines."""
    link = c.folder / "printer"
    pty = read_lines(start(c.spawn, c.runs, c.folder))[0]  # it prints the pty's path; the link points there
    assert pty.startswith("/dev/pts/") and link.resolve() == Path(pty)
    with serial.Serial(str(link), 115200, timeout=1) as port:
        port.write(b"M303 E0 S210 C8\n")
        lines = expect(port, r"^ok$", M303_TIMEOUT_S)
    assert any(line.startswith("PID Autotune finished!") for line in lines), lines
    assert [line.split()[1] for line in lines if line.startswith("#define DEFAULT_K")] == \
        ["DEFAULT_Kp", "DEFAULT_Ki", "DEFAULT_Kd"], lines


def check_klipper_config(c: Command) -> None:
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    config = (c.folder / "printer.cfg").read_text().splitlines()
    assert config[-1] == CONFIG_END and f"serial: {c.folder / 'twin-mcu'}" in config


def check_klipper_mcu(c: Command) -> None:
    """The MCU on its link: its address, then the same sections; the link is a pseudo-terminal."""
    link = c.folder / "twin-mcu"
    lines = read_lines(start(c.spawn, c.runs, c.folder), CONFIG_END)
    assert lines[0] == str(link) and f"serial: {link}" in lines
    assert link.is_symlink() and link.resolve().as_posix().startswith("/dev/pts/")


def check_tune(c: Command) -> None:
    """An answer, proven: new gains ready to paste, or keep your gains; and the plot."""
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    answers = [line for line in done.stdout.splitlines() if line.startswith("answer: ")]
    assert len(answers) == 1, done.stdout
    if answers[0].startswith("answer: new gains"):
        assert re.search(r"^  M301 E0 P\S+ I\S+ D\S+$", done.stdout, re.M), done.stdout
    else:
        assert answers[0].startswith("answer: keep "), answers  # your gains, or the autotune's where you gave none
    assert list((c.folder / "twin-out").glob("twin-tune-*.png"))


def check_kalico_tune(c: Command) -> None:
    """An answer on Kalico's loop, proven: Kalico's [extruder] section, or keep your gains."""
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    answers = [line for line in done.stdout.splitlines() if line.startswith("answer: ")]
    # the Ender 5's hotend: no plant reproduces its PID_CALIBRATE, so keep your gains before any loop runs
    assert len(answers) == 1 and ("loop kalico" in done.stdout or CANNOT_MODEL in answers[0]), done.stdout
    if answers[0].startswith("answer: new gains"):
        assert re.search(r"^Kalico printer.cfg .*\n  \[extruder\]\n  pid_version: 1\n  control: pid\n  pid_kp: \S+\n",
                         done.stdout, re.M), done.stdout
    else:
        assert answers[0].startswith("answer: keep "), answers


def check_seeds(c: Command) -> None:
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("Seed 000: ")
    verdicts = re.findall(r"\s(reproduced|fitted|differs|impossible): ", done.stdout)
    assert len(verdicts) > 10 and "reproduced" in verdicts


def check_compare(c: Command) -> None:
    done = run(c.runs, c.folder)
    assert done.returncode == 0, done.stderr
    assert "PID_CALIBRATE" in done.stdout and re.search(r"^summary: .*out-of-sample", done.stdout, re.M)
    assert png(c.folder / "compare.png")


CASES: dict[str, Case] = {
    "python3 -m venv .venv && .venv/bin/pip install -e '.[test,plot,fast,lint,seeds]' && .venv/bin/pip install "
    "--no-deps Printrun==2.2.0 && .venv/bin/twin-sim": Case(check_install_and_run),
    '.venv/bin/python -m pytest -m "not slow" -n auto': Case(check_quick_tests, slow=False),
    ".venv/bin/python -m pytest -n auto": Case(check_ci_tests, slow=False),
    "twin-sim --plot docs/heat_hold_pid.png": Case(check_plot),
    "twin-sim --firmware fuzzy_pi": Case(check_sim),
    "twin-sim --help": Case(check_help, slow=False),
    "twin-serial --link /tmp/printer": Case(check_serial),
    "twin-klipper-mcu --print-config --link /tmp/twin-mcu > printer.cfg": Case(check_klipper_config, slow=False),
    "twin-klipper-mcu --link /tmp/twin-mcu": Case(check_klipper_mcu),
    "twin-tune --plant hotend_cartridge --target 210": Case(check_tune),
    "twin-tune --plant seed003_third --target 210": Case(check_tune),
    "twin-tune --from-log my_m303.txt": Case(check_tune, logs=True),
    "twin-tune --from-log klippy.log --loop kalico": Case(check_kalico_tune, logs=True),
    "twin-fit --help": Case(check_help, slow=False),
    "python -m tools.seeds 000": Case(check_seeds),
    "twin-compare klippy.log --plot compare.png": Case(check_compare, logs=True),
}
# Commands whose full run costs minutes, and the flags the README shows for a cheaper run of them.
CHEAPER = {
    "twin-tune --plant hotend_cartridge --target 210": "--budget 90 --proof 2",
    "twin-tune --plant seed003_third --target 210": "--budget 90 --proof 2",
    "twin-tune --from-log my_m303.txt": "--budget 90 --proof 2",
    "twin-tune --from-log klippy.log --loop kalico": "--budget 90 --proof 2",
    "python -m tools.seeds 000": "--budget 3",
}
COMMANDS = readme_commands(README.read_text())


def test_every_case_is_a_readme_command():
    assert sorted(set(CASES) - set(COMMANDS)) == []


@pytest.mark.parametrize("flags", sorted(set(CHEAPER.values())))
def test_the_cheaper_flags_are_the_readmes_own(flags):
    assert f"`{flags}`" in README.read_text()
    assert {word for word in flags.split() if word.startswith("--")} <= CHEAP_FLAGS


@pytest.mark.parametrize("command", [
    pytest.param(c, marks=[pytest.mark.slow] if c in CASES and CASES[c].slow else [], id=c) for c in COMMANDS])
def test_readme_command(command, tmp_path, spawn, request):
    case = CASES.get(command)
    assert case is not None, f"README command without a case in tests/test_readme.py: {command}"
    logs = request.getfixturevalue("hardware_logs") if case.logs else None
    cheaper = f" {CHEAPER[command]}" if command in CHEAPER else ""
    case.check(Command(command, as_run(command + cheaper, tmp_path, logs), tmp_path, spawn))
