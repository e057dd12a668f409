"""Hypothesis profiles: 'dev' (quick, random) and 'ci' (derandomised, more examples); the AVR toolchain;
the hardware logs; servers a test starts, always stopped.

CI sets CI=true, which selects 'ci'; HYPOTHESIS_PROFILE overrides either way. What a clone may lack (the
AVR toolchain, ../shared/hardware_logs, an extra) skips a test locally with the reason and fails it in CI,
except in CI's jobs that build a user's install (HEATER_TWIN_SKIP_MISSING=1, .ci/run): there it skips, as
it does for that user.
"""

import os
import subprocess
from pathlib import Path
from typing import NoReturn

import pytest
from hypothesis import HealthCheck, settings

from firmware_port.avr.toolchain import Toolchain, ToolchainMissing, find_toolchain
from tools.klipper_host.session import stop_process
from tools.logs.location import hardware_logs_dir

STOP_TIMEOUT_S = 20  # a test's server gets this long to exit after SIGTERM, then SIGKILL

settings.register_profile("dev", max_examples=100, deadline=None)
settings.register_profile(
    "ci",
    max_examples=400,
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE") or ("ci" if os.environ.get("CI") else "dev"))


@pytest.fixture(scope="session")
def avr_toolchain() -> Toolchain:
    """avr-gcc, avr-libc, binutils-avr and libsimavr (tests marked avr): without them a test fails
    in CI (CI set) and skips elsewhere, with one line naming the packages."""
    try:
        return find_toolchain()
    except ToolchainMissing as exc:
        unavailable(str(exc))


def unavailable(reason: str) -> NoReturn:
    """What a test needs is missing: it fails in CI (CI set, HEATER_TWIN_SKIP_MISSING not 1) and skips
    elsewhere, with ``reason``; at a module's top level too (the module's tests skip, and none errs)."""
    if os.environ.get("CI") and os.environ.get("HEATER_TWIN_SKIP_MISSING") != "1":
        pytest.fail(reason, pytrace=False)
    pytest.skip(reason, allow_module_level=True)


@pytest.fixture(scope="session")
def hardware_logs() -> Path:
    """The captured hardware logs (tools.logs.location: $HEATER_TWIN_HARDWARE_LOGS, else ../shared/hardware_logs).
    A clone without them skips the test locally and fails it in CI. Every test that reads a capture, itself
    or through a library function, asks for this fixture (or ``hardware_log``)."""
    try:
        return hardware_logs_dir()
    except FileNotFoundError as exc:
        unavailable(str(exc))


def pytest_generate_tests(metafunc):
    """``@pytest.mark.each_hardware_log(pattern, exclude=names)``: one case per capture matching the glob
    ``pattern``, named by its file, run with the ``hardware_log`` fixture; the folder is read here, at
    collection, never at import. Without the folder there is one case, which ``hardware_logs`` skips (fails
    in CI)."""
    marker = metafunc.definition.get_closest_marker("each_hardware_log")
    if marker is None:
        return
    pattern, exclude = marker.args[0], set(marker.kwargs.get("exclude", ()))
    try:
        names = sorted(p.name for p in hardware_logs_dir().glob(pattern) if p.name not in exclude)
    except FileNotFoundError:
        names = []
    metafunc.parametrize("hardware_log", names or [pytest.param(None, id="no-capture")], indirect=True)


@pytest.fixture
def hardware_log(request, hardware_logs: Path) -> Path:
    """The capture of a test marked ``each_hardware_log`` (see pytest_generate_tests)."""
    if request.param is None:
        marker = request.node.get_closest_marker("each_hardware_log")
        pytest.fail(f"no capture in {hardware_logs} matches {marker.args[0]!r}", pytrace=False)
    return hardware_logs / request.param


@pytest.fixture
def spawn():
    """``spawn(args, **popen_kwargs)`` starts a process that is always stopped at teardown:
    terminated, then killed if it has not exited within STOP_TIMEOUT_S."""
    processes: list[subprocess.Popen] = []

    def start(args, **kwargs) -> subprocess.Popen:
        processes.append(subprocess.Popen(args, **kwargs))
        return processes[-1]

    yield start
    for proc in processes:
        stop_process(proc, STOP_TIMEOUT_S)
