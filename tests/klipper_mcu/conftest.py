"""A running twin MCU with the registry's klippy on it (tools/klipper_host/session.py).

klippy comes from its own venv ($HEATER_TWIN_KLIPPY_VENV, else .venv-klippy; .ci/run builds it);
without it a test skips locally and fails under CI=true. Sessions run at SPEED x real time, klippy
under libfaketime at the same factor, and in the MCU's lenient timing mode: a loaded 2-core CI
machine may stall either process for tens of milliseconds, which strict mode would turn into a
"Timer too close" shutdown (strict mode is tested on a virtual clock: test_mcu.py).
"""

from __future__ import annotations

import pytest

from tests.conftest import unavailable
from tools.klipper_host.session import KLIPPY_VENV_ENV, KlipperSession, Missing, faketime_env, venv_command

SPEED = 10.0


@pytest.fixture
def klipper(tmp_path):
    """``klipper(*mcu_args, **options)`` starts a session (stopped at teardown) and returns it."""
    try:
        venv_command(KLIPPY_VENV_ENV)
        faketime_env(SPEED)
    except Missing as exc:
        unavailable(str(exc))
    sessions: list[KlipperSession] = []

    def start(*mcu_args: str, **options) -> KlipperSession:
        workdir = tmp_path / f"session{len(sessions)}"
        workdir.mkdir()
        sessions.append(KlipperSession(workdir, speed=SPEED, mcu_args=mcu_args, **options))
        return sessions[-1]

    yield start
    for session in sessions:
        session.close()
