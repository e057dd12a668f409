"""Without numba the batch gives the same answers, slower (twin/batch_kernel.py ``HEATER_TWIN_KERNEL``).

CI's environment has numba, so these tests run the fallback in a process of its own with numba's JIT
disabled (NUMBA_DISABLE_JIT=1: numba's decorators return the Python functions, ``compiled()`` is False)
and HEATER_TWIN_KERNEL=numpy, what a platform without numba's wheels runs by default: the numpy lanes
where they run, the batch's loop as plain Python elsewhere. Its readings, records, trips and score totals
must equal this process's compiled ones exactly, for every plant kind and every lane law
(tests/twin/fallback_cases.py); and twin-tune must print the same answer either way.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.twin import fallback_cases
from twin import batch_kernel
from twin.batch import BatchTwin
from twin.batch_kernel import KERNEL_ENV
from twin.lane_noise import draw
from twin.plants import make_plant

ROOT = Path(__file__).resolve().parents[2]
FALLBACK_ENV = {"NUMBA_DISABLE_JIT": "1", KERNEL_ENV: "numpy"}
TIMEOUT_S = 3600  # a bound for a loaded machine, not a budget: the fallback's cost is docs/performance.md's
ENDER3_LOG = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"


def _fallback(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """argv run by this interpreter without numba's JIT, on the numpy kernel."""
    env = {**os.environ, **FALLBACK_ENV, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, *argv], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=TIMEOUT_S)


@pytest.fixture(scope="module")
def compiled() -> None:
    """Numba compiles here (else there is no compiled run to compare with)."""
    if not batch_kernel.compiled():
        pytest.skip("numba does not compile here: nothing to compare the fallback with")


@pytest.mark.slow
def test_every_plant_and_law_reads_the_same_without_numba(compiled, tmp_path, monkeypatch):
    """Plant kinds x lane laws (Marlin's, Klipper's, Kalico's, a user's) x noise: the fallback's run and
    the compiled run, every array equal."""
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    out = tmp_path / "fallback.npz"
    done = _fallback(["-m", "tests.twin.fallback_cases", str(out)], tmp_path)
    assert done.returncode == 0, done.stderr
    fallback = np.load(out)
    compared = 0
    for name, run in fallback_cases.cases().items():
        mine = run()
        for key, value in mine.items():
            theirs = fallback[f"{name}#{key}"]
            if key == "kernel":
                assert (str(value), str(theirs)) == ("numba", "numpy"), name
                continue
            np.testing.assert_array_equal(theirs, value, err_msg=f"{name}: {key}")
            compared += 1
    assert len({k.split("#")[0] for k in fallback.files}) == len(fallback_cases.cases()) == 48
    assert compared > 400


def _answer(stdout: str) -> str:
    """twin-tune's report without its wall time."""
    return re.sub(r"^\(\d+(\.\d+)? s\)$", "", stdout, flags=re.MULTILINE)


def _assert_same_answer(args: list[str], cwd: Path) -> None:
    """twin-tune ARGS --budget 90 --proof 2 prints the same report with numba and without its JIT on the
    numpy kernel."""
    argv = ["-m", "tools.cli.tune", *args, "--budget", "90", "--proof", "2", "--plot", "none"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with_numba = subprocess.run([sys.executable, *argv], cwd=cwd, env=env, capture_output=True, text=True,
                                timeout=TIMEOUT_S)
    without = _fallback(argv, cwd)
    assert with_numba.returncode == 0, with_numba.stderr
    assert without.returncode == 0, without.stderr
    assert "answer:" in with_numba.stdout
    assert _answer(without.stdout) == _answer(with_numba.stdout)


@pytest.mark.slow
def test_the_default_tune_answers_the_same_without_numba(compiled, tmp_path, monkeypatch):
    """A linear plant: the numpy lanes."""
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    _assert_same_answer(["--plant", "hotend_cartridge", "--target", "210"], tmp_path)


@pytest.mark.slow
def test_a_from_log_tune_answers_the_same_without_numba(compiled, hardware_logs, tmp_path, monkeypatch):
    """The Ender-3 V3 SE's M303 capture: an FOPDT, its dead time on the numpy lanes' ring."""
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    _assert_same_answer(["--from-log", str(hardware_logs / ENDER3_LOG)], tmp_path)


def test_a_period_without_a_sample_draws_no_noise():
    """The numpy lanes' period that ends before the ADC's next conversion (a scenario event there) draws
    (streams, 0) normals: a reshape to (-1, 0) once failed there ("cannot reshape array of size 0")."""
    generators = [np.random.default_rng(1), np.random.default_rng(2)]
    assert draw(generators, 0).shape == (2, 0)
    assert draw(generators, 3).shape == (2, 3)
    batch = BatchTwin(make_plant("hotend_cartridge"), [fallback_cases.LAWS["pid"]()[0]] * 2, kernel="numpy",
                      noise_lsb=1.0, seed=[1, 2])
    batch.set_target(210)
    for t_s in (0.001, 0.002, 0.5):  # the first two stretches end between two samples
        batch.run_until(t_s)
    assert batch.result().hotend.measured_c.shape[1] == 2


@pytest.mark.parametrize("preset", ["seed003_third", "seed001_fopdt"])
@pytest.mark.parametrize("noise", [{}, {"noise_lsb": [1.0, 2.5, 1.0], "seed": [3, 3, 7]}], ids=["quiet", "noisy"])
def test_dead_time_on_the_numpy_lanes_is_the_compiled_loop(preset, noise):
    """The numpy lanes' ring of past pulses (twin/lane_ring.py) against the compiled loop's: seed 003's 5 s
    and seed 001's 20.7 s dead time (its MAXTEMP trip included), every reading, record and trip equal."""
    gains = fallback_cases.LAWS["pid"]()
    runs = []
    for kernel in ("numpy", "numba"):
        batch = BatchTwin(make_plant(preset), gains, kernel=kernel, **noise)
        assert batch.numpy_lanes_run()
        batch.set_target(210)
        batch.run_until(250.0)
        runs.append((batch.result().hotend, batch.trips()))
    (mine, my_trips), (theirs, their_trips) = runs
    for name in ("measured_c", "duty", "block_c", "sensor_c"):
        np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name), err_msg=name)
    assert my_trips == their_trips


@pytest.mark.parametrize("plant", ["dead time", "radiating"])
def test_the_numpy_kernel_runs_every_plant_and_law(plant):
    """kernel='numpy' takes what only the loop runs (dead time, a radiating loss, a law that reads the
    board) and gives the compiled loop's readings (here numba's: the plain-Python run is above)."""
    runs = []
    for kernel in ("numpy", "numba"):
        batch = BatchTwin(fallback_cases.PLANTS[plant](), fallback_cases.LAWS["mpc"](), kernel=kernel)
        batch.set_target(210)
        batch.run_until(30.0)
        runs.append(batch.result().hotend)
    np.testing.assert_array_equal(runs[0].measured_c, runs[1].measured_c)
    np.testing.assert_array_equal(runs[0].block_c, runs[1].block_c)


def test_numba_with_its_jit_disabled_is_no_numba(monkeypatch):
    """NUMBA_DISABLE_JIT: the loop is plain Python, so the default kernel is numpy, as without numba."""
    if batch_kernel.numba is None:
        pytest.skip("numba is not installed")
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    monkeypatch.setattr(batch_kernel.numba.config, "DISABLE_JIT", 1)
    assert not batch_kernel.compiled() and batch_kernel.default_kernel() == "numpy"
    assert "plain Python" in batch_kernel.describe()
    monkeypatch.setattr(batch_kernel.numba.config, "DISABLE_JIT", 0)
    assert batch_kernel.compiled() and batch_kernel.default_kernel() == "numba"
