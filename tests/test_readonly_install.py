"""Every CLI for a user who can write neither the install nor a home (a service account, a read-only
container): no traceback. The package is copied to a read-only folder whose ``__pycache__`` entries are
regular files (so neither Python nor numba can cache beside the sources, even as root), HOME is a file
(no ~/.cache), NUMBA_CACHE_DIR is unset; numba's cache then goes to a private folder under TMPDIR
(twin/numba_cache.py). One subprocess runs each command's ``main`` in turn: --help, or a tiny run."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import unavailable
from twin import numba_cache

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("firmware_port", "twin", "protocol", "tools")
DRIVER = """
import contextlib, io, json, sys, traceback
runs = json.loads(sys.argv[1])
results = []
for module, argv in runs:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            status = __import__(module, fromlist=["main"]).main(argv)
        except SystemExit as exc:
            status = exc.code or 0
        except BaseException:
            traceback.print_exc()
            status = "raised"
    results.append([module, status, err.getvalue()])
print(json.dumps(results))
"""


def _read_only_copy(target: Path) -> None:
    for package in PACKAGES:
        shutil.copytree(ROOT / package, target / package, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for folder in [target, *(p for p in target.rglob("*") if p.is_dir())]:
        if (folder / "__init__.py").exists():
            (folder / "__pycache__").write_text("")  # a file: no cache folder can be made here
    for path in [*target.rglob("*"), target]:
        path.chmod(0o555 if path.is_dir() else 0o444)


def _writable_again(target: Path) -> None:
    for path in [target, *target.rglob("*")]:
        path.chmod(stat.S_IMODE(path.stat().st_mode) | stat.S_IWUSR)


@pytest.mark.slow  # every CLI started once: 13 s on a quiet 2-core machine
def test_every_cli_runs_without_a_writable_install_or_home(tmp_path):
    install, home, temp, out = tmp_path / "install", tmp_path / "home", tmp_path / "tmp", tmp_path / "out"
    install.mkdir()
    temp.mkdir()
    home.write_text("")  # HOME is a file: ~/.cache cannot exist
    _read_only_copy(install)
    try:
        runs = [
            ("tools.cli.sim", ["--duration", "1", "--no-bed", "--no-plot", "--out", str(out)]),
            ("tools.cli.serial", ["--help"]),
            ("tools.cli.fit", ["--help"]),
            ("tools.cli.compare", ["--help"]),
            ("tools.cli.tune", ["--help"]),
            ("tools.cli.firmware_report", ["--help"]),
            ("tools.cli.hold_check", ["--gains", "13,0.3,70", "--seeds", "1", "--duration", "2", "--hold-from", "1"]),
            ("tools.seeds.__main__", ["--help"]),
            # the batch twin, whose compiled loop is cached in the user's private folder (twin/numba_cache.py): the
            # commands above no longer import it (their start-up loads only what they run)
            ("tools.bench", ["twin", "--duration", "5", "--lanes", "4"]),
        ]
        env = {key: value for key, value in os.environ.items()
               if key not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "MPLCONFIGDIR", "PYTHONPATH")}
        env.update(HOME=str(home), TMPDIR=str(temp), PYTHONPATH=str(install), PYTHONDONTWRITEBYTECODE="")
        done = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(runs)], cwd=install, env=env,
                              capture_output=True, text=True, timeout=1800)
    finally:
        _writable_again(install)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    results = json.loads(done.stdout)
    for module, status, err in results:
        assert "Traceback" not in err and "no locator available" not in err, (module, err)
        assert status in ((0, 1) if module == "tools.cli.hold_check" else (0,)), (module, status, err)
    assert (out / "heat_hold_pid_nobed.csv").is_file()
    if importlib.util.find_spec("numba") is not None:  # its cache went to the user's private folder
        folder = temp / f"{numba_cache.FALLBACK_PREFIX}{os.getuid()}"
        assert folder.is_dir() and stat.S_IMODE(folder.stat().st_mode) == 0o700


@pytest.fixture
def numba(monkeypatch):
    """numba as it is for that user: only NUMBA_CACHE_DIR could hold a cache, and it is unset (``CacheImpl``'s
    locators are numba's own list, and CI runs these tests against numba: a rename fails them there)."""
    if importlib.util.find_spec("numba") is None:
        unavailable("numba is not installed (pip install '.[fast]')")
    import numba
    from numba.core import caching

    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [caching.UserProvidedCacheLocator])
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    return numba


def _double(x):
    return 2 * x


def test_the_cache_goes_to_a_private_temporary_folder(numba, monkeypatch, tmp_path, capsys):
    with pytest.raises(RuntimeError, match="no locator available"):  # what every CLI raised at import
        numba.njit(cache=True)(_double)
    monkeypatch.setattr(numba_cache.tempfile, "tempdir", str(tmp_path))
    compiled = numba_cache.cached_njit(_double)
    assert compiled(21) == 42
    folder = tmp_path / f"{numba_cache.FALLBACK_PREFIX}{os.getuid()}"
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700 and any(folder.rglob("*.nbi"))  # numba's index, written
    assert numba.config.CACHE_DIR == "" and capsys.readouterr().err == ""


def test_a_folder_others_can_write_is_not_used_and_the_kernel_compiles_uncached(numba, monkeypatch, tmp_path,
                                                                                capsys):
    """numba's cache files are pickles: a folder another user could write would let them run code here."""
    monkeypatch.setattr(numba_cache.tempfile, "tempdir", str(tmp_path))
    shared = tmp_path / f"{numba_cache.FALLBACK_PREFIX}{os.getuid()}"
    shared.mkdir()
    shared.chmod(0o777)
    assert numba_cache.private_cache_folder() is None
    numba_cache._say_uncached.cache_clear()
    compiled = numba_cache.cached_njit(_double)
    assert compiled(4) == 8 and not any(shared.iterdir())
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "compile on every run" in err
