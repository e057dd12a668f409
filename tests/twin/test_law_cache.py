"""A lane law's compiled loop is cached in the user's cache folder (``$XDG_CACHE_HOME/heater-twin/laws``), one
folder per law and source version, and a law's old versions are pruned (twin/numba_cache.py)."""

from __future__ import annotations

import importlib.util
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import unavailable
from twin import numba_cache
from twin.numba_cache import LAW_VERSIONS_KEPT, law_cache_folder

ROOT = Path(__file__).resolve().parents[2]
LAW_KEY = "my_laws.pi"


def _step_in(path: Path):
    """A law's step, imported from a file of its own (so that its source file's time can be set)."""
    path.write_text("def pi_step(p, s, temp_q5, target_c, board):\n    return 0\n")
    spec = importlib.util.spec_from_file_location("my_laws", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.pi_step


def _used_at(folder: Path, time_s: float) -> Path:
    folder.mkdir(parents=True)
    os.utime(folder, (time_s, time_s))
    return folder


def test_a_laws_versions_live_in_the_users_cache_folder_and_the_stale_ones_are_pruned(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    step = _step_in(tmp_path / "my_laws.py")
    edited_s = 1_700_000_000.0
    os.utime(tmp_path / "my_laws.py", (edited_s, edited_s))
    law_folder = tmp_path / "cache" / "heater-twin" / "laws" / LAW_KEY
    before_the_edit = _used_at(law_folder / "a1", edited_s - 100.0)
    since = [_used_at(law_folder / f"b{i}", edited_s + 10.0 * i) for i in range(1, LAW_VERSIONS_KEPT + 1)]
    other_law = _used_at(tmp_path / "cache" / "heater-twin" / "laws" / "my_laws.other" / "c1", edited_s - 100.0)

    folder = law_cache_folder(LAW_KEY, 0xABC, step)

    assert folder == law_folder / "abc" and stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert folder.stat().st_mtime > since[-1].stat().st_mtime  # marked as used now
    kept = since[-(LAW_VERSIONS_KEPT - 1):]  # with the current one, LAW_VERSIONS_KEPT versions
    assert sorted(law_folder.iterdir()) == sorted([folder, *kept])
    assert not before_the_edit.exists() and other_law.is_dir()  # only this law's versions are pruned
    assert law_cache_folder(LAW_KEY, 0xABC, step) == folder and sorted(law_folder.iterdir()) == sorted([folder, *kept])


def test_without_a_writable_cache_folder_numba_chooses(tmp_path, monkeypatch):
    blocked = tmp_path / "a file"
    blocked.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))  # no folder can be made under a file
    assert law_cache_folder(LAW_KEY, 0xABC, _step_in(tmp_path / "my_laws.py")) is None


def _double(x):
    return 2 * x


def test_cached_njit_caches_in_the_folder_it_is_given(tmp_path):
    if importlib.util.find_spec("numba") is None:
        unavailable("numba is not installed (pip install '.[fast]')")
    import numba

    saved = numba.config.CACHE_DIR
    compiled = numba_cache.cached_njit(_double, tmp_path / "law")
    assert compiled(21) == 42
    assert any((tmp_path / "law").rglob("*.nbi")) and numba.config.CACHE_DIR == saved


# Runs a user's law (tests/helpers/integer_pi.py) on the compiled batch and prints where numba cached its loop
# and what it loaded from there.
DRIVER = """
import json
from tests.helpers.integer_pi import INTEGER_PI_LAW, IntegerPi
from twin import batch_kernel
from twin.batch import BatchTwin
from twin.plants import make_plant
batch = BatchTwin(make_plant("hotend"), [IntegerPi(20.0, 1.0), IntegerPi(5.0, 0.2)], kernel="numba")
batch.hotend.target_c = 200
batch.run(2)
stats = batch_kernel.law_kernel(INTEGER_PI_LAW).stats
print(json.dumps([stats.cache_path, sum(stats.cache_hits.values())]))
"""


@pytest.mark.slow
def test_a_users_law_compiles_into_the_users_cache_folder_and_loads_from_there(tmp_path):
    if importlib.util.find_spec("numba") is None:
        unavailable("numba is not installed (pip install '.[fast]')")
    env = {key: value for key, value in os.environ.items() if key not in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT")}
    env.update(XDG_CACHE_HOME=str(tmp_path), PYTHONPATH=str(ROOT))
    runs = [json.loads(subprocess.run([sys.executable, "-c", DRIVER], env=env, cwd=ROOT, capture_output=True,
                                      text=True, check=True).stdout) for _ in range(2)]
    law_folder = tmp_path / "heater-twin" / "laws" / "tests.helpers.integer_pi.integer_pi"
    (version,) = law_folder.iterdir()
    assert [path for path, _ in runs] == [str(p) for p in version.iterdir()] * 2
    assert [hits for _, hits in runs] == [0, 1]  # compiled, then loaded
