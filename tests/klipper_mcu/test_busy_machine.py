"""The klipper fixture on a busy machine: a failure off the MCU's schedule runs again slower, once per speed;
a failure on schedule, or at the last speed, stands (conftest.py). No klippy needed."""

from __future__ import annotations

import pytest

from tests.klipper_mcu.conftest import SPEEDS, Klipper
from tools.klipper_host.session import KlipperSession


def stopped_session(tmp_path, klippy_log: str, mcu_err: str) -> KlipperSession:
    """A session's files as a run left them, without its processes."""
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "klippy.log").write_text(klippy_log)
    (tmp_path / "mcu.err").write_text(mcu_err)
    session = object.__new__(KlipperSession)
    session.workdir, session.log_path, session._processes = tmp_path, tmp_path / "klippy.log", []
    return session


ON_TIME = "twin-klipper-mcu: lenient timing: 0 late events (up to 0.0 ms late), 0 max_duration misses forgiven " \
    "(up to 0.0 ms after it); MCU clock\n"
LATE = "twin-klipper-mcu: WARNING: lenient timing: 12 late events (up to 3611.0 ms late), 0 max_duration misses " \
    "forgiven (up to 0.0 ms after it); MCU clock\n"


@pytest.mark.parametrize(("klippy_log", "mcu_err", "why"), [
    ("Configured MCU 'mcu' (1024 moves)\n", ON_TIME, None),
    ("", LATE + ON_TIME.replace("0 late", "1 late"), "the MCU: 1 late events, 0 max_duration misses forgiven"),
    ("", ON_TIME.replace("0 max_duration", "3 max_duration"), "the MCU: 0 late events, 3 max_duration misses forgiven"),
    ("mcu 'mcu': Timeout on connect\n", ON_TIME, "klippy: Timeout on connect"),
    ("Transition to shutdown state: Lost communication with MCU 'mcu'\n", ON_TIME,
     "klippy: Lost communication with MCU"),
])
def test_missed_schedule_reads_klippy_and_the_mcu(tmp_path, klippy_log, mcu_err, why):
    assert stopped_session(tmp_path, klippy_log, mcu_err).missed_schedule() == why


def test_a_run_off_schedule_runs_again_slower_until_the_last_speed(tmp_path):
    runner = Klipper(tmp_path)
    for slower in SPEEDS[1:]:
        runner.sessions = [stopped_session(tmp_path / f"s{slower}", "", LATE)]
        why = runner.slow_down()
        assert why is not None and why.endswith(f"runs again at {slower:g} x") and runner.speed == slower
    runner.sessions = [stopped_session(tmp_path / "last", "", LATE)]
    assert runner.slow_down() is None and runner.speed == SPEEDS[-1]


def test_a_failure_on_schedule_stands(tmp_path):
    runner = Klipper(tmp_path)
    runner.sessions = [stopped_session(tmp_path, "", ON_TIME)]
    assert runner.slow_down() is None and runner.speed == SPEEDS[0]
