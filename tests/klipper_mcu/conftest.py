"""A running twin MCU with the registry's klippy on it (tools/klipper_host/session.py).

klippy comes from its own venv ($HEATER_TWIN_KLIPPY_VENV, else .venv-klippy; .ci/run builds it);
without it a test skips locally and fails under CI=true. Sessions run in the MCU's lenient timing
mode at SPEEDS[0] x real time, klippy under libfaketime at the same factor (strict mode is tested
on a virtual clock: test_mcu.py).

A busy machine. At S x real time klippy's own windows shrink to 1/S of wall time: 5 s to identify
the MCU and five unanswered clock queries become 0.5 s at 10 x, and a heater update is due 0.3 s
after the report it answers, 30 ms. With other processes on both cores klippy misses them: it
says "Timeout on connect" or "Lost communication", or the MCU forgives late events, which moves
PID_CALIBRATE's relay. Such a run says nothing about the twin, so an attempt that fails where its
session missed the schedule (session.py's ``missed_schedule``) runs again, from the start, at
the next of SPEEDS, with a warning that says why; at 1 x klippy has the windows a real printer
gives it. A failure on schedule, or at the last speed, stands. One mechanism (``Klipper.attempt``)
for both places a session starts: a fixture that starts one with what runs on it (Moonraker, the
agent: ``klipper.fixture(what, start)``), whose setup would otherwise fail before the body's re-run
could help, and a test's body (pytest_pyfunc_call below), which starts its fixtures' sessions again
before it runs again.
"""

from __future__ import annotations

import subprocess
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple, TypeVar

import pytest

from tests.conftest import unavailable
from tools.klipper_host.session import (
    KLIPPY_VENV_ENV,
    KlipperSession,
    Missing,
    faketime_env,
    missed_schedule,
    stop_process,
    venv_command,
)

SPEEDS = (10.0, 4.0, 1.0)
T = TypeVar("T")


class Mark(NamedTuple):
    """Where an attempt began: how many session folders (a failed start's too), sessions and processes were held."""

    folders: int
    sessions: int
    processes: int


BEGINNING = Mark(0, 0, 0)


class Klipper:
    """The ``klipper`` fixture: ``klipper(*mcu_args, **options)`` starts a session at the current speed
    (stopped at teardown) and returns it; ``klipper.spawn(args, **popen_kwargs)`` starts a process that
    runs on it (stopped before the sessions); ``klipper.attempt(what, start)`` runs ``start`` until it is not
    off schedule, and ``klipper.fixture(what, start)`` does so for a fixture, whose start the test's body may
    run again. ``session_class`` is KlipperSession but in the mechanism's own tests."""

    def __init__(self, tmp_path, session_class: Callable[..., KlipperSession] = KlipperSession):
        self.tmp_path = tmp_path
        self.session_class = session_class
        self.speeds = list(SPEEDS)
        self.sessions: list[KlipperSession] = []  # the running attempts'
        self.processes: list[subprocess.Popen] = []  # likewise
        self.folders: list[Path] = []  # likewise, a failed start's too
        self.fixtures: list[tuple[str, Callable[[], object], object]] = []  # (what, start, value) of each fixture
        self.started = 0  # in all attempts, for their folders: session0, session1, ...

    def __repr__(self) -> str:
        return f"Klipper({self.speed:g} x, {len(self.sessions)} sessions, {len(self.processes)} processes)"

    @property
    def speed(self) -> float:
        return self.speeds[0]

    def __call__(self, *mcu_args: str, **options) -> KlipperSession:
        workdir = self.tmp_path / f"session{self.started}"
        workdir.mkdir()
        self.started += 1
        self.folders.append(workdir)
        self.sessions.append(self.session_class(workdir, speed=self.speed, mcu_args=mcu_args, **options))
        return self.sessions[-1]

    def spawn(self, args: list[str], **popen_kwargs) -> subprocess.Popen:
        self.processes.append(subprocess.Popen(args, **popen_kwargs))
        return self.processes[-1]

    def mark(self) -> Mark:
        return Mark(len(self.folders), len(self.sessions), len(self.processes))

    def fixture(self, what: str, start: Callable[[], T]) -> T:
        """``attempt(what, start)``, for a fixture: kept, so that a test's body failing off schedule can
        start it again slower (pytest_pyfunc_call)."""
        value = self.attempt(what, start)
        self.fixtures.append((what, start, value))
        return value

    def attempt(self, what: str, start: Callable[[], T], since: Mark | None = None) -> T:
        """``start()``'s value. While it raises off schedule with a lower speed left, what it started (what the
        runner held ``since``: by default from the call) is stopped and it runs again at the next speed, with
        a pytest warning that says why (``what`` runs)."""
        since = self.mark() if since is None else since  # the same after each slow down: it drops what came after
        while True:
            try:
                return start()
            except Exception:
                why = self.slow_down(since)
                if why is None:
                    raise
                warnings.warn(f"{why}: {what} runs again at {self.speed:g} x", pytest.PytestWarning, stacklevel=2)

    def slow_down(self, since: Mark = BEGINNING) -> str | None:
        """After a failed attempt: what it started (since ``since``) is stopped; if one of its sessions missed
        the MCU's schedule (one whose start failed too) and a lower speed is left, the next attempt takes it,
        and this says what was missed at which speed (None: the failure stands)."""
        self._stop(since)
        missed = [why for folder in self.folders[since.folders:] if (why := missed_schedule(folder))]
        if not missed or len(self.speeds) == 1:
            return None
        was = self.speeds.pop(0)
        del self.folders[since.folders:], self.sessions[since.sessions:], self.processes[since.processes:]
        return f"{missed[0]} at {was:g} x real time"

    def close(self) -> None:
        self._stop(BEGINNING)

    def _stop(self, since: Mark) -> None:
        for proc in reversed(self.processes[since.processes:]):  # what runs on the sessions first
            stop_process(proc)
        for session in self.sessions[since.sessions:]:
            session.close()


@pytest.fixture
def klipper(tmp_path):
    try:
        venv_command(KLIPPY_VENV_ENV)
        faketime_env(SPEEDS[0])
    except Missing as exc:
        unavailable(str(exc))
    runner = Klipper(tmp_path)
    yield runner
    runner.close()


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem):
    """A test with the ``klipper`` fixture runs again slower while it fails off schedule; the sessions its
    fixtures started (with ``klipper.fixture``) are stopped and started again before it, at the new speed."""
    runner = pyfuncitem.funcargs.get("klipper")
    if not isinstance(runner, Klipper):
        return None
    args = {name: pyfuncitem.funcargs[name] for name in pyfuncitem._fixtureinfo.argnames}
    restarts = [(name, what, start) for what, start, value in runner.fixtures
                for name, arg in args.items() if arg is value]
    runs = 0

    def run() -> None:
        nonlocal runs
        for name, what, start in restarts if runs else ():
            args[name] = runner.attempt(what, start)
        runs += 1
        pyfuncitem.obj(**args)

    runner.attempt("the test", run, BEGINNING)
    return True
