"""Klipper's own code referees the port: klippy 0.12.0.dev276's ControlPID, ControlBangBang, Heater
PWM rules, ControlAutoTune (PID_CALIBRATE) and verify_heater, from the registry, in their own venv
(klippy_driver.py), against firmware_port/klipper with KLIPPY_0_12's switches, on the same steps.
Every record of every step is compared bit for bit (JSON floats round-trip exactly).

Per law: a twin run (KlipperTwin on the stock hotend, noisy ADC: a heat-up and hold at 200 C, or
PID_CALIBRATE at 200 C) and seeded random walks, MIN_READINGS sensor reports or more; hypothesis
sequences on top; and a changed constant in the port must show as mismatches.
"""

from __future__ import annotations

import itertools
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import firmware_port.klipper.heater as port_heater
import firmware_port.klipper.pid_calibrate as port_calibrate
import firmware_port.klipper.verify_heater as port_verify
from tests.conftest import unavailable
from tests.firmware_port.klipper.referee.port_steps import LAWS, build_case, cases_for, readings, run_port
from tools.klipper_host.session import KLIPPY_VENV_ENV, Missing, venv_command

pytestmark = pytest.mark.slow

DRIVER = Path(__file__).with_name("klippy_driver.py")
MIN_READINGS = 10_000  # per law
TIMEOUT_S = 900  # a hang guard: a busy machine is many times slower


class Klippy:
    """klippy_driver.py in the klippy venv: one case in, klippy's records out."""

    def __init__(self, python: Path):
        self.proc = subprocess.Popen([str(python), str(DRIVER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, cwd=DRIVER.parent.parent)

    def run(self, cases: list[dict]) -> list[dict]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        results = []
        for case in cases:  # one at a time: a full pipe each way would deadlock
            self.proc.stdin.write(json.dumps(case) + "\n")
            self.proc.stdin.flush()
            line = self.proc.stdout.readline()
            assert line, f"klippy_driver.py stopped (exit {self.proc.poll()})"
            results.append(json.loads(line))
        return results

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=TIMEOUT_S)


@pytest.fixture(scope="module")
def klippy():
    try:
        python = venv_command(KLIPPY_VENV_ENV).with_name("python")
    except Missing as exc:
        unavailable(str(exc))
    driver = Klippy(python)
    yield driver
    driver.close()


def mismatches(klippy: Klippy, cases: list[dict]) -> list[str]:
    """Each case's first differing record, as "law case k step j: klippy ... port ..."."""
    out = []
    for k, (case, theirs) in enumerate(zip(cases, klippy.run(cases))):
        ours = json.loads(json.dumps(run_port(case)))  # the same JSON round trip as klippy's side
        if ours == theirs:
            continue
        for j, (a, b) in enumerate(zip(theirs["records"], ours["records"])):
            if a != b:
                out.append(f"{case['law']} case {k} step {j} {case['steps'][j]}: klippy {a} port {b}")
                break
        else:
            out.append(f"{case['law']} case {k}: klippy {theirs} port {ours}")
    return out


@pytest.mark.parametrize("law", LAWS)
def test_port_equals_klippy_bit_for_bit(klippy, law):
    cases = cases_for(law, MIN_READINGS, seed=LAWS.index(law))
    assert sum(readings(c) for c in cases) >= MIN_READINGS
    assert mismatches(klippy, cases) == []


@given(seed=st.integers(0, 2**32 - 1), temps=st.lists(st.floats(-10, 330), min_size=1, max_size=120),
       gaps=st.lists(st.sampled_from([0.3, 0.299, 0.301, 1.0, 4.9, 5.1, 30.0]), min_size=1, max_size=120),
       law=st.sampled_from(LAWS))
def test_port_equals_klippy_on_hypothesis_sequences(klippy, seed, temps, gaps, law):
    times = list(itertools.accumulate(gaps[k % len(gaps)] for k in range(len(temps))))
    case = build_case(law, list(zip(times, temps)), np.random.default_rng(seed))  # config and targets: seeded
    assert mismatches(klippy, [case]) == []


@pytest.mark.parametrize(("law", "module", "name", "value"), [
    ("pid", port_heater, "PID_PARAM_BASE", 256.0),
    ("pid", port_heater, "AMBIENT_TEMP", 25.5),
    ("watermark", port_heater, "MIN_PWM_CHANGE_BEFORE_2026_03_VALUE", 1.5),  # no step from 0 is ever sent
    ("pwm", port_heater, "MIN_PWM_CHANGE_BEFORE_2026_03_VALUE", 0.051),
    ("pwm", port_heater, "MAX_HEAT_TIME", {**port_heater.MAX_HEAT_TIME, port_heater.PWM_RESEND_BEFORE_2025_04: 4.9}),
    ("autotune", port_calibrate, "TUNE_PID_DELTA", 5.5),
    ("verify", port_verify, "CHECK_INTERVAL_S", 1.001),
    ("verify", port_heater, "QUELL_STALE_TIME", {**port_heater.QUELL_STALE_TIME,
                                                 port_heater.QUELL_STALE_BEFORE_2025_07: 7.0}),
])
def test_a_changed_constant_in_the_port_is_caught(klippy, monkeypatch, law, module, name, value):
    monkeypatch.setattr(module, name, value)
    cases = cases_for(law, 3000, seed=LAWS.index(law))
    assert mismatches(klippy, cases), f"{name} = {value} went unnoticed"
