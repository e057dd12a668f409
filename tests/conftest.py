"""Hypothesis profiles: 'dev' (quick, random) and 'ci' (derandomised, more examples); the AVR toolchain.

CI sets CI=true, which selects 'ci'; HYPOTHESIS_PROFILE overrides either way.
"""

import os

import pytest
from hypothesis import HealthCheck, settings

from firmware_port.avr.toolchain import Toolchain, ToolchainMissing, find_toolchain

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
