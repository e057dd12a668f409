"""The klipper fixture on a busy machine: a failure off the MCU's schedule runs again slower, once per speed;
a failure on schedule, or at the last speed, stands (conftest.py), whether a test's body or a fixture
started the session. No klippy needed: the sessions here are files a run left, or fakes."""

from __future__ import annotations

import sys

import pytest

from tests.klipper_mcu.conftest import SPEEDS, Klipper
from tools.klipper_host import api as api_module
from tools.klipper_host.api import KlippyApi, KlippyError
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
        was = runner.speed
        assert runner.slow_down() == f"the MCU: 12 late events, 0 max_duration misses forgiven at {was:g} x real time"
        assert runner.speed == slower
    runner.sessions = [stopped_session(tmp_path / "last", "", LATE)]
    assert runner.slow_down() is None and runner.speed == SPEEDS[-1]


def test_a_failure_on_schedule_stands(tmp_path):
    runner = Klipper(tmp_path)
    runner.sessions = [stopped_session(tmp_path, "", ON_TIME)]
    assert runner.slow_down() is None and runner.speed == SPEEDS[0]


class FakeSession:
    """A session that starts nothing; off the MCU's schedule (klippy timed out) above 1 x real time."""

    def __init__(self, workdir, *, speed: float, mcu_args: tuple[str, ...] = (), on_schedule: bool = False):
        self.workdir, self.speed, self.on_schedule, self.closed = workdir, speed, on_schedule, False

    def missed_schedule(self) -> str | None:
        return None if self.on_schedule or self.speed == 1 else "klippy: Timeout on connect"

    def close(self) -> None:
        self.closed = True


class FakeStart:
    """What a fixture starts: a session, and a process on it whose readiness wait fails above 1 x."""

    def __init__(self, runner: Klipper, **options):
        self.runner, self.options = runner, options
        self.sessions: list[FakeSession] = []
        self.processes: list = []
        self.value: FakeSession | None = None  # what the fixture returned

    def __call__(self) -> FakeSession:
        self.sessions.append(self.runner(**self.options))
        self.processes.append(self.runner.spawn([sys.executable, "-c", "import time; time.sleep(600)"]))
        assert self.sessions[-1].speed == 1, "Moonraker never saw klippy ready"
        return self.sessions[-1]


@pytest.fixture
def fake_klipper(tmp_path):
    runner = Klipper(tmp_path, session_class=FakeSession)
    yield runner
    runner.close()


@pytest.fixture
def late_fixture(recwarn, fake_klipper) -> FakeStart:
    """A fixture that starts its session with ``klipper.attempt``, as test_twin_tune.py's ``printer`` does."""
    start = FakeStart(fake_klipper)
    start.value = fake_klipper.attempt("the late fixture", start)
    return start


def test_a_fixture_session_off_schedule_starts_again_slower(late_fixture, fake_klipper, recwarn):
    assert late_fixture.value is late_fixture.sessions[-1]
    assert [session.speed for session in late_fixture.sessions] == list(SPEEDS)
    assert [session.closed for session in late_fixture.sessions] == [True, True, False]  # until teardown
    assert [proc.poll() is None for proc in late_fixture.processes] == [False, False, True]
    assert [str(warning.message) for warning in recwarn if warning.category is pytest.PytestWarning] == [
        "klippy: Timeout on connect at 10 x real time: the late fixture runs again at 4 x",
        "klippy: Timeout on connect at 4 x real time: the late fixture runs again at 1 x"]
    assert fake_klipper.sessions == [late_fixture.value]


def test_a_fixture_session_failing_on_schedule_fails_once(fake_klipper, recwarn):
    start = FakeStart(fake_klipper, on_schedule=True)
    with pytest.raises(AssertionError, match="Moonraker never saw klippy ready"):
        fake_klipper.attempt("the fixture", start)
    assert [session.speed for session in start.sessions] == [SPEEDS[0]] and start.sessions[0].closed
    assert start.processes[0].poll() is not None
    assert not [warning for warning in recwarn if warning.category is pytest.PytestWarning]


class SteppingClock:
    """``time`` for api.py: each reading 10 s after the last, sleeps free (no wall clock in the test)."""

    def __init__(self):
        self.now_s = 0.0

    def monotonic(self) -> float:
        self.now_s += 10.0
        return self.now_s

    def sleep(self, seconds: float) -> None:
        pass


@pytest.mark.parametrize("log_grows", [True, False])
def test_klippy_starting_slowly_is_waited_for_while_its_log_grows(monkeypatch, log_grows):
    """wait_ready's hang guard (60 s) counts from the last change of ``progress`` (the session passes klippy.log's
    size): 20 polls in startup take 200 s of the clock, which a log that grows at each poll allows."""
    states = iter(["startup"] * 20 + ["ready"])
    api = object.__new__(KlippyApi)
    monkeypatch.setattr(api, "info", lambda: {"state": next(states), "state_message": "Printer is not ready"})
    monkeypatch.setattr(api_module, "time", SteppingClock())
    progress = iter(range(100)).__next__ if log_grows else lambda: 0
    if log_grows:
        assert api.wait_ready(60.0, progress)["state"] == "ready"
    else:
        with pytest.raises(KlippyError, match="klippy is startup: Printer is not ready"):
            api.wait_ready(60.0, progress)
