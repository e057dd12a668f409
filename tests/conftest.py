"""Hypothesis profiles: 'dev' (quick, random) and 'ci' (derandomised, more examples); the AVR toolchain;
servers a test starts, always stopped.

CI sets CI=true, which selects 'ci'; HYPOTHESIS_PROFILE overrides either way.
"""

import os
import subprocess

import pytest
from hypothesis import HealthCheck, settings

from firmware_port.avr.toolchain import Toolchain, ToolchainMissing, find_toolchain

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
        if os.environ.get("CI"):
            pytest.fail(str(exc), pytrace=False)
        pytest.skip(str(exc))
def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes over about 5 s (leave out locally with -m 'not slow')")


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
        if proc.poll() is None:
            proc.terminate()
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=STOP_TIMEOUT_S)
