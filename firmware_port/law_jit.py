"""A lane law's plain Python made callable from numba-compiled code, and the options every compiled piece
shares.

A law is written in plain Python (firmware_port/lane_law.py); twin's batch loop compiles it in
(twin/batch_kernel.py ``law_kernel``) and ``register`` compiles it once to check it
(firmware_port/law_check.py). Both make its functions jitable here, once each: numba is imported only
when a law is compiled, and without numba a law stays the Python it is.
"""

from __future__ import annotations

import hashlib
import inspect
import types
from collections.abc import Callable

import numpy as np

# The loop allocates nothing (its scratch arrays come in), so it runs without numba's reference
# counting: passing arrays to the inlined helpers would otherwise cost an atomic increment and
# decrement each, per period, more than the arithmetic (0.96 s against 0.39 s of CPU for 1000
# lanes x 600 s on the 2-core reference machine). ``_nrt`` is numba's own switch for that runtime
# (underscored, so not promised: tests/firmware_port/marlin/test_lanes.py, run against numba in CI, would catch a change).
# A law compiled with these options cannot build a list, a dict or a string: ``register`` says so.
NUMBA_OPTIONS = {"_nrt": False, "error_model": "numpy"}

_JITABLE: set[Callable] = set()


def jitable(fn: Callable) -> Callable:
    """A law's plain-Python function made callable from compiled code (inlined there), with every
    module-level plain function it calls; the function itself, unchanged, without numba."""
    if fn in _JITABLE:
        return fn
    try:
        from numba.extending import register_jitable
    except ImportError:  # without numba the law runs as the Python it is
        return fn
    _JITABLE.add(fn)
    register_jitable(**NUMBA_OPTIONS)(fn)
    for value in globals_read(fn).values():
        if isinstance(value, types.FunctionType):
            jitable(value)
    return fn


def globals_read(fn: Callable) -> dict[str, object]:
    """The module-level names a function's code (and its nested code) reads, with their values."""
    names: set[str] = set()
    codes = [fn.__code__]
    while codes:
        code = codes.pop()
        names.update(code.co_names)
        codes.extend(c for c in code.co_consts if isinstance(c, types.CodeType))
    return {name: fn.__globals__[name] for name in names if name in fn.__globals__}


def functions_reached(*fns: Callable) -> list[Callable]:
    """``fns`` and every module-level plain function they call, directly or not, each once."""
    found: list[Callable] = []
    todo = list(fns)
    while todo:
        fn = todo.pop(0)
        if fn not in found:
            found.append(fn)
            todo.extend(v for v in globals_read(fn).values() if isinstance(v, types.FunctionType))
    return found


def source_hash(*fns: Callable) -> int:
    """A hash of what compiled code made of ``fns`` is made of: their source, that of every plain function they
    call, and the module-level constants those read; positive, non-zero, under 2**56 (a closure variable in
    numba's cache key, so that an edited law compiles afresh)."""
    parts: list[str] = []
    seen: set[Callable] = set()

    def walk(fn: Callable) -> None:
        if fn in seen:
            return
        seen.add(fn)
        try:
            parts.append(inspect.getsource(fn))
        except OSError:  # defined where no source is kept (an interactive session): its bytecode
            parts.append(fn.__code__.co_code.hex())
        for name, value in sorted(globals_read(fn).items()):
            if isinstance(value, types.FunctionType):
                walk(value)
            elif isinstance(value, np.ndarray):
                parts.append(f"{name}={value.dtype}{value.shape}{value.tobytes().hex()}")
            elif not isinstance(value, types.ModuleType):
                parts.append(f"{name}={value!r}")

    for fn in fns:
        walk(fn)
    digest = hashlib.sha256("\n".join(parts).encode()).digest()
    return int.from_bytes(digest[:7], "little") | 1
