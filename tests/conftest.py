"""Hypothesis profiles: 'dev' (quick, random) and 'ci' (derandomised, more examples).

CI sets CI=true, which selects 'ci'; HYPOTHESIS_PROFILE overrides either way.
"""

import os

from hypothesis import HealthCheck, settings

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


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes over about 5 s (leave out locally with -m 'not slow')")
