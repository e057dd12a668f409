"""numba's ``cache=True`` for a user who cannot write where numba keeps its cache.

numba caches compiled code in NUMBA_CACHE_DIR, else beside the source (``__pycache__``), else in
the user's cache folder (~/.cache); with none writable (a service account, a read-only container)
``njit(cache=True)`` raises "no locator available" at import, and every command would fail. Then
the cache goes to a folder of this user's own under the temporary directory, or, if there is none
to be had safely, nowhere: the kernels compile on each run, said once on stderr.

The fallback folder is the user's alone (created 0700, owned by them, not a symlink): numba's
cache files are pickles, and a folder another user could write would let them run code here.

A lane law's compiled loop (twin/batch_kernel.py ``law_kernel``: one per law, a user's too) is cached in
the user's cache folder instead, one folder per law and version of its source (``law_cache_folder``), so
that an edited law neither writes into the library's folder nor leaves its old builds behind for ever.
"""

from __future__ import annotations

import functools
import inspect
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from firmware_port.user_cache import user_cache_dir

FALLBACK_PREFIX = "heater-twin-numba-"  # + the user id, in the temporary directory
LAWS_FOLDER = "laws"  # in the user's cache folder: <law>/<source version>/ numba's files
LAW_VERSIONS_KEPT = 4  # versions of one law's compiled loop kept, the most recently used


def cached_njit(fn: Callable, folder: Path | None = None, **options: Any) -> Callable:
    """``numba.njit(cache=True, **options)(fn)``, with the cache in ``folder`` when given, else where numba
    chooses; in a private temporary folder, or no cache, where numba finds no writable cache folder."""
    import numba

    if folder is not None:
        compiled = _cached_in(numba, fn, folder, options)
        if compiled is not None:
            return compiled
    try:
        return numba.njit(cache=True, **options)(fn)
    except RuntimeError as exc:
        if not _no_locator(exc):
            raise
    private = private_cache_folder()
    if private is not None:
        compiled = _cached_in(numba, fn, private, options)
        if compiled is not None:
            return compiled
    _say_uncached()
    return numba.njit(**options)(fn)


def _cached_in(numba: Any, fn: Callable, folder: Path, options: dict[str, Any]) -> Callable | None:
    """``njit(cache=True)`` with its cache in ``folder`` (None where numba cannot write there)."""
    config = numba.config
    saved = config.CACHE_DIR
    config.CACHE_DIR = str(folder)  # read when the function's cache locator is chosen
    try:
        return numba.njit(cache=True, **options)(fn)
    except RuntimeError as exc:
        if not _no_locator(exc):
            raise
        return None
    finally:
        config.CACHE_DIR = saved


def _no_locator(exc: RuntimeError) -> bool:
    """numba.core.caching's "cannot cache function ...: no locator available for file ..."."""
    return "no locator available" in str(exc)


def private_cache_folder() -> Path | None:
    """This user's folder for numba's cache under the temporary directory, or None if it cannot be made
    or is not theirs alone."""
    try:
        folder = Path(tempfile.gettempdir()) / f"{FALLBACK_PREFIX}{os.getuid()}"
        try:
            folder.mkdir(mode=0o700)
        except FileExistsError:
            pass
        info = folder.lstat()
    except OSError:  # no usable temporary directory at all
        return None
    private = stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and not info.st_mode & 0o077
    return folder if private else None


def law_cache_folder(law_key: str, source: int, step: Callable) -> Path | None:
    """The folder of one version of a lane law's compiled loop, ``<user cache>/laws/<law_key>/<source>``
    (made 0700 and marked as used now), or None where it cannot be written. The law's other versions are
    pruned: those last used before the file of its ``step`` last changed, and all but the
    LAW_VERSIONS_KEPT - 1 most recently used."""
    law_folder = user_cache_dir() / LAWS_FOLDER / re.sub(r"[^\w.-]", "_", law_key)
    folder = law_folder / f"{source:x}"
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        os.utime(folder)
    except OSError:
        return None
    if not os.access(folder, os.W_OK | os.X_OK):
        return None
    source_file = _source_file(step)
    _prune(law_folder, folder, _mtime(Path(source_file)) if source_file else None)
    return folder


def _source_file(fn: Callable) -> str | None:
    """The file a function's source is in (None for one typed into an interpreter)."""
    try:
        return inspect.getsourcefile(fn)
    except TypeError:
        return None


def _prune(law_folder: Path, current: Path, source_changed_s: float | None) -> None:
    """Remove the law's versions but ``current`` that were last used before its source changed, or that
    are not among the most recently used."""
    used = [(_mtime(other), other) for other in law_folder.iterdir() if other != current and other.is_dir()]
    ranked = sorted(((used_s, other) for used_s, other in used if used_s is not None), reverse=True)
    for rank, (used_s, other) in enumerate(ranked, start=2):  # the current version is the first
        if rank > LAW_VERSIONS_KEPT or source_changed_s is not None and used_s < source_changed_s:
            shutil.rmtree(other, ignore_errors=True)  # another process may be pruning it too


def _mtime(path: Path) -> float | None:
    try:
        return path.stat().st_mtime
    except OSError:
        return None


@functools.cache
def _say_uncached() -> None:
    print("heater-twin: no writable folder for numba's cache (set NUMBA_CACHE_DIR): the kernels compile on "
          "every run", file=sys.stderr)
