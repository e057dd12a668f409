"""A running twin MCU with the registry's klippy on it (tools/klipper_host/session.py).

klippy comes from its own venv ($HEATER_TWIN_KLIPPY_VENV, else .venv-klippy; .ci/run builds it);
without it a test skips locally and fails under CI=true. Sessions run in the MCU's lenient timing
mode at SPEEDS[0] x real time, klippy under libfaketime at the same factor (strict mode is tested
on a virtual clock: test_mcu.py).

A busy machine. At S x real time klippy's own windows shrink to 1/S of wall time: 5 s to identify
the MCU and five unanswered clock queries become 0.5 s at 10 x, and a heater update is due 0.3 s
after the report it answers, 30 ms. With other processes on both cores klippy misses them: it
says "Timeout on connect" or "Lost communication", or the MCU forgives late events, which moves
PID_CALIBRATE's relay. Such a run says nothing about the twin, so a test that fails where its
session missed the schedule (``KlipperSession.missed_schedule``) runs again, from the start, at
the next of SPEEDS, with a warning that says why; at 1 x klippy has the windows a real printer
gives it. A failure on schedule, or at the last speed, fails the test.
"""

from __future__ import annotations

import warnings

import pytest

from tests.conftest import unavailable
from tools.klipper_host.session import KLIPPY_VENV_ENV, KlipperSession, Missing, faketime_env, venv_command

SPEEDS = (10.0, 4.0, 1.0)


class Klipper:
    """The ``klipper`` fixture: ``klipper(*mcu_args, **options)`` starts a session at the current speed
    (stopped at teardown) and returns it."""

    def __init__(self, tmp_path):
        self.tmp_path = tmp_path
        self.speeds = list(SPEEDS)
        self.sessions: list[KlipperSession] = []  # this attempt's
        self.started = 0  # in all attempts, for their folders

    def __repr__(self) -> str:
        return f"Klipper({self.speed:g} x, {len(self.sessions)} sessions)"

    @property
    def speed(self) -> float:
        return self.speeds[0]

    def __call__(self, *mcu_args: str, **options) -> KlipperSession:
        workdir = self.tmp_path / f"session{self.started}"
        workdir.mkdir()
        self.started += 1
        self.sessions.append(KlipperSession(workdir, speed=self.speed, mcu_args=mcu_args, **options))
        return self.sessions[-1]

    def close(self) -> None:
        for session in self.sessions:
            session.close()

    def slow_down(self) -> str | None:
        """After a failure: the sessions stopped; if one missed the MCU's schedule and a lower speed is
        left, the next attempt takes it, and this says why (None: the failure stands)."""
        self.close()
        missed = [why for session in self.sessions if (why := session.missed_schedule())]
        if not missed or len(self.speeds) == 1:
            return None
        was = self.speeds.pop(0)
        self.sessions = []
        return f"{missed[0]} at {was:g} x real time: the test runs again at {self.speed:g} x"


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
    """A test whose sessions all start in its body runs again slower while it fails off schedule."""
    runner = pyfuncitem.funcargs.get("klipper")
    if not isinstance(runner, Klipper) or runner.sessions:  # none, or a fixture started one: once, as usual
        return None
    args = {name: pyfuncitem.funcargs[name] for name in pyfuncitem._fixtureinfo.argnames}
    while True:
        try:
            pyfuncitem.obj(**args)
            return True
        except Exception:
            why = runner.slow_down()
            if why is None:
                raise
            warnings.warn(why, pytest.PytestWarning, stacklevel=1)
