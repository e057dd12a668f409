"""The klipper fixture on a busy machine: a failure off the MCU's schedule runs again slower, once per speed;
a failure on schedule, or at the last speed, stands (conftest.py), whether a test's body or a fixture
started the session, and whether its start failed or what ran on it. No klippy needed: the sessions
here are fakes that leave the files a run leaves."""

from __future__ import annotations

import sys

import pytest

from tests.klipper_mcu.conftest import SPEEDS, Klipper
from tools.klipper_host import api as api_module
from tools.klipper_host.api import KlippyApi, KlippyError
from tools.klipper_host.session import missed_schedule

ON_TIME = "twin-klipper-mcu: lenient timing: 0 late events (up to 0.0 ms late), 0 max_duration misses forgiven " \
    "(up to 0.0 ms after it); MCU clock\n"
LATE = "twin-klipper-mcu: WARNING: lenient timing: 12 late events (up to 3611.0 ms late), 0 max_duration misses " \
    "forgiven (up to 0.0 ms after it); MCU clock\n"
TIMEOUT = "mcu 'mcu': Timeout on connect\n"


def leave_files(folder, klippy_log: str, mcu_err: str) -> None:
    """A session's files as a run left them."""
    folder.mkdir(exist_ok=True)
    (folder / "klippy.log").write_text(klippy_log)
    (folder / "mcu.err").write_text(mcu_err)


@pytest.mark.parametrize(("klippy_log", "mcu_err", "why"), [
    ("Configured MCU 'mcu' (1024 moves)\n", ON_TIME, None),
    ("", LATE + ON_TIME.replace("0 late", "1 late"), "the MCU: 1 late events, 0 max_duration misses forgiven"),
    ("", ON_TIME.replace("0 max_duration", "3 max_duration"), "the MCU: 0 late events, 3 max_duration misses forgiven"),
    (TIMEOUT, ON_TIME, "klippy: Timeout on connect"),
    ("Transition to shutdown state: Lost communication with MCU 'mcu'\n", ON_TIME,
     "klippy: Lost communication with MCU"),
    ("MCU 'mcu' configured for 72Mhz but running at 0Mhz!\n", ON_TIME,  # its clock sync started from time 0
     "klippy: configured for 72Mhz but running at 0Mhz"),
])
def test_missed_schedule_reads_klippy_and_the_mcu(tmp_path, klippy_log, mcu_err, why):
    leave_files(tmp_path, klippy_log, mcu_err)
    assert missed_schedule(tmp_path) == why


def test_a_start_that_failed_before_klippy_wrote_is_on_schedule(tmp_path):
    assert missed_schedule(tmp_path) is None


class FakeSession:
    """Starts nothing; leaves the files of a run with ``mcu_err`` (LATE above 1 x real time, else ON_TIME) and
    ``klippy_log``; raises as KlipperSession does when klippy never got ready, if ``start_fails``."""

    def __init__(self, workdir, *, speed: float, mcu_args: tuple[str, ...] = (), klippy_log: str = "",
                 mcu_err: str | None = None, start_fails: bool = False):
        self.workdir, self.speed, self.closed = workdir, speed, False
        leave_files(workdir, klippy_log, mcu_err or (LATE if speed > 1 else ON_TIME))
        if start_fails:
            raise KlippyError("klippy is error: mcu 'mcu': Unable to connect")

    def close(self) -> None:
        self.closed = True


def test_a_run_off_schedule_runs_again_slower_until_the_last_speed(tmp_path):
    runner = Klipper(tmp_path, session_class=FakeSession)
    for slower in SPEEDS[1:]:
        mark, was = runner.mark(), runner.speed
        runner(mcu_err=LATE)
        assert runner.slow_down(mark) == f"the MCU: 12 late events, 0 max_duration misses forgiven at {was:g} x real time"
        assert runner.speed == slower and runner.sessions == []
    mark = runner.mark()
    runner(mcu_err=LATE)
    assert runner.slow_down(mark) is None and runner.speed == SPEEDS[-1]


def test_a_failure_on_schedule_stands(tmp_path):
    runner = Klipper(tmp_path, session_class=FakeSession)
    runner(mcu_err=ON_TIME)
    assert runner.slow_down() is None and runner.speed == SPEEDS[0]


def test_only_the_failed_attempts_sessions_count(tmp_path):
    """A session late before the attempt began (a fixture's, say) is not the attempt's, and stays up."""
    runner = Klipper(tmp_path, session_class=FakeSession)
    earlier = runner(mcu_err=LATE)
    mark = runner.mark()
    runner(mcu_err=ON_TIME)
    assert runner.slow_down(mark) is None and runner.speed == SPEEDS[0] and not earlier.closed


class FakeStart:
    """What a fixture starts: a session, and a process on it whose readiness wait fails above 1 x."""

    def __init__(self, runner: Klipper, **options):
        self.runner, self.options = runner, options
        self.sessions: list[FakeSession] = []
        self.processes: list = []
        self.value: FakeSession | None = None  # what the fixture returned

    def __call__(self) -> FakeSession:
        self.processes.append(self.runner.spawn([sys.executable, "-c", "import time; time.sleep(600)"]))
        self.sessions.append(self.runner(**self.options))
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
        "the MCU: 12 late events, 0 max_duration misses forgiven at 10 x real time: the late fixture runs again at 4 x",
        "the MCU: 12 late events, 0 max_duration misses forgiven at 4 x real time: the late fixture runs again at 1 x"]
    assert fake_klipper.sessions == [late_fixture.value]


def test_a_session_whose_start_failed_off_schedule_starts_again_slower(fake_klipper, recwarn):
    """klippy's 'Timeout on connect' until it gave up: the session raised, and was never returned or held."""
    speeds: list[float] = []

    def start() -> FakeSession:
        speeds.append(fake_klipper.speed)
        return fake_klipper(klippy_log=TIMEOUT if fake_klipper.speed > 1 else "", start_fails=fake_klipper.speed > 1)

    assert fake_klipper.attempt("the fixture", start).speed == 1 and speeds == list(SPEEDS)
    assert [str(warning.message) for warning in recwarn if warning.category is pytest.PytestWarning] == [
        "klippy: Timeout on connect at 10 x real time: the fixture runs again at 4 x",
        "klippy: Timeout on connect at 4 x real time: the fixture runs again at 1 x"]


def test_a_fixture_session_failing_on_schedule_fails_once(fake_klipper, recwarn):
    start = FakeStart(fake_klipper, mcu_err=ON_TIME)
    with pytest.raises(AssertionError, match="Moonraker never saw klippy ready"):
        fake_klipper.attempt("the fixture", start)
    assert [session.speed for session in start.sessions] == [SPEEDS[0]] and start.sessions[0].closed
    assert start.processes[0].poll() is not None
    assert not [warning for warning in recwarn if warning.category is pytest.PytestWarning]


class BodyRuns(Klipper):
    """The ``klipper`` runner on fake sessions, with the speeds a test's body ran at."""

    def __init__(self, tmp_path):
        super().__init__(tmp_path, session_class=FakeSession)
        self.body_speeds: list[float] = []


@pytest.fixture
def klipper(tmp_path):
    """conftest.py's runner (and its pytest_pyfunc_call) on fake sessions: late above 1 x real time."""
    runner = BodyRuns(tmp_path)
    yield runner
    runner.close()


@pytest.fixture
def fake_printer(klipper) -> FakeSession:
    return klipper.fixture("the fake printer fixture", klipper)


def test_a_body_failing_off_schedule_starts_its_fixtures_session_again_slower(fake_printer, klipper, recwarn):
    """The body fails while the fixture's session was late (above 1 x): the fixture's session starts again
    slower, and the body runs again on it."""
    klipper.body_speeds.append(fake_printer.speed)
    assert fake_printer.speed == 1, "what the twin did, late"
    assert klipper.body_speeds == list(SPEEDS) and klipper.sessions == [fake_printer]
    assert [str(warning.message) for warning in recwarn if warning.category is pytest.PytestWarning] == [
        "the MCU: 12 late events, 0 max_duration misses forgiven at 10 x real time: the test runs again at 4 x",
        "the MCU: 12 late events, 0 max_duration misses forgiven at 4 x real time: the test runs again at 1 x"]


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
