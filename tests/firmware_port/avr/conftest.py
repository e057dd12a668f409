"""Fixtures of the AVR tests: one booted simulator per law, and the differential check that
counts the steps it compares (the toolchain fixture, avr_toolchain, is in tests/conftest.py)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import pytest

from firmware_port.avr.laws import LAWS
from firmware_port.avr.runner import LawSim, compare
from firmware_port.avr.toolchain import Toolchain

STEPS = pytest.StashKey[Counter]()


def pytest_configure(config: pytest.Config) -> None:
    config.stash[STEPS] = Counter()


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    steps = config.stash[STEPS]
    if steps:
        per_law = ", ".join(f"{name} {count}" for name, count in sorted(steps.items()))
        terminalreporter.write_line(f"AVR differential: {sum(steps.values())} steps compared bit for bit ({per_law})")


@pytest.fixture(scope="session")
def law_sims(avr_toolchain: Toolchain) -> dict[str, LawSim]:
    """One booted simulator per law (each comparison powers it up again)."""
    return {name: LawSim(law) for name, law in LAWS.items()}


@pytest.fixture(scope="session")
def differential(law_sims: dict[str, LawSim], pytestconfig: pytest.Config) -> Callable[[str, Any, Sequence[tuple]], None]:
    """check(law name, settings, input records): the AVR build and the Python port agree on every
    field after every step; counts the steps (the power-up included)."""

    def check(name: str, settings: Any, records: Sequence[tuple]) -> None:
        mismatch = compare(law_sims[name], settings, records)
        assert mismatch is None, f"{name}: {mismatch}"
        pytestconfig.stash[STEPS][name] += len(records) + 1

    return check
