"""numba's ``cache=True`` for a user who cannot write where numba keeps its cache.

numba caches compiled code in NUMBA_CACHE_DIR, else beside the source (``__pycache__``), else in
the user's cache folder (~/.cache); with none writable (a service account, a read-only container)
``njit(cache=True)`` raises "no locator available" at import, and every command would fail. Then
the cache goes to a folder of this user's own under the temporary directory, or, if there is none
to be had safely, nowhere: the kernels compile on each run, said once on stderr.

The fallback folder is the user's alone (created 0700, owned by them, not a symlink): numba's
cache files are pickles, and a folder another user could write would let them run code here.
"""

from __future__ import annotations

import functools
import os
import stat
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

FALLBACK_PREFIX = "heater-twin-numba-"  # + the user id, in the temporary directory


def cached_njit(fn: Callable, **options: Any) -> Callable:
    """``numba.njit(cache=True, **options)(fn)``, with the cache in a private temporary folder, or no
    cache, where numba finds no writable cache folder."""
    import numba

    try:
        return numba.njit(cache=True, **options)(fn)
    except RuntimeError as exc:
        if not _no_locator(exc):
            raise
    folder = private_cache_folder()
    if folder is not None:
        config = numba.config
        saved = config.CACHE_DIR  # type: ignore[attr-defined]
        config.CACHE_DIR = str(folder)  # type: ignore[attr-defined]  # read when the function's cache locator is chosen
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError as exc:
            if not _no_locator(exc):
                raise
        finally:
            config.CACHE_DIR = saved  # type: ignore[attr-defined]
    _say_uncached()
    return numba.njit(**options)(fn)


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


@functools.cache
def _say_uncached() -> None:
    print("heater-twin: no writable folder for numba's cache (set NUMBA_CACHE_DIR): the kernels compile on "
          "every run", file=sys.stderr)
