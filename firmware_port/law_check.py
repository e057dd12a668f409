"""What ``register`` checks of a lane law, so that a mistake in a user's law surfaces where it is registered, in
one paragraph, rather than at its first batch run as a numba traceback inside the batch loop.

The check compiles the law's ``step`` (and ``tuned``) once, with the options and for the types the batch
loop gives it (one lane of the law's own records, int64 readings, the ``BoardInputs`` record), where numba
compiles; without numba (or with NUMBA_DISABLE_JIT) it runs the step once on the same tiny input as plain
Python, as the numpy lanes would. It also checks that the controller class has an attribute for every
record field the batch packs from it. A mistake is a ``LawError`` naming the law, the file and line of the
user's code at fault and the field or name involved; numba's (or Python's) full message is its ``details``.
"""

from __future__ import annotations

import ast
import inspect
import linecache
import os
import re
import textwrap
import traceback
import warnings
from collections.abc import Callable
from typing import Any, NoReturn

import numpy as np

from firmware_port.law_jit import NUMBA_OPTIONS, functions_reached, jitable, source_hash
from firmware_port.user_error import UserError

# The tiny input: zero parameters and state, a reading of 190 C (Q5), 10 C below its target.
TEMP_Q5 = np.int64(190 << 5)
TARGET_C = np.int64(200)
UNCHECKED = object()  # a plain-Python run whose return cannot be checked
SUBSET = "A law's step keeps to the Python numba compiles (listed in firmware_port/lane_law.py's docstring)"


class LawError(UserError):
    """A lane law the batch cannot run, said in one paragraph; ``details``: numba's (or Python's) full message."""

    def __init__(self, message: str, details: str = ""):
        super().__init__(message)
        self.details = details


class _Fault(Exception):
    """What is wrong (``what``), the name involved, and where, as found; ``details``: the full message."""

    def __init__(self, what: str, name: str | None = None, where: tuple[str, int] | None = None, details: str = ""):
        super().__init__(what)
        self.what, self.name, self.where, self.details = what, name, where, details


def check_law(law: Any, board: np.dtype) -> None:
    """LawError if ``law`` (a LaneLaw) cannot run on the batch: a record field its controller class lacks, a step
    (or ``tuned``) outside numba's subset or returning anything but one integer. ``board``: BoardInputs' dtype."""
    functions = functions_reached(law.step, *([law.tuned] if law.tuned else []))
    try:
        _check_fields(law)
        args = tuple(np.zeros(1, dtype).view(np.recarray) for dtype in (law.params, law.state, board))
        for fn, kind in [(law.step, "step"), *([(law.tuned, "tuned")] if law.tuned else [])]:
            _check_function(fn, kind, args, functions)
    except _Fault as fault:
        raise LawError(_paragraph(law, fault, functions), fault.details) from fault.__cause__


def _paragraph(law: Any, fault: _Fault, functions: list[Callable]) -> str:
    """The one paragraph: the law, what is wrong, where (file, line, the line itself), what to read next."""
    where = fault.where or (_locate(fault.name, functions) if fault.name else None) or _def_line(law.step)
    path, line = where
    relative = os.path.relpath(path)
    shown = path if relative.startswith("..") else relative
    code = linecache.getline(path, line).strip()
    at = f", at {shown} line {line}{': ' + code if code else ''}" if line else ""
    more = f" {SUBSET}; the full message is the LawError's details." if fault.details else ""
    return f"lane law {law.name!r} ({law.controller.__name__}): {fault.what}{at}.{more}"


# -- the record fields a class must have -------------------------------------------------------------------------


def _check_fields(law: Any) -> None:
    """Every params field (unless the law packs its own) and state field (unless it reads its own) must be an
    attribute the controller class sets: the batch packs each lane's records from its controller."""
    params = [] if law.pack else list(law.params.names or ())
    fields = params + ([] if law.read else list(law.state.names or ()))
    known = _attributes_set(law.controller)
    missing = [name for name in fields if known is not None and name not in known]
    if missing:
        cls, name = law.controller, missing[0]
        own = "pack (its params)" if name in params else "read and write (its state)"
        raise _Fault(f"the record field {name!r} is no attribute of {cls.__name__} (the batch packs each lane's records "
                     f"from its controller's attributes of the fields' names): set self.{name} in the class, or give "
                     f"the law its own {own}", name, _def_line(cls))


def _attributes_set(cls: type) -> set[str] | None:
    """The names of ``cls``'s class attributes and of every ``self.NAME`` its methods (and its bases') assign;
    None where that cannot be told (no source; a setattr, a ``__dict__`` or a ``__getattr__``)."""
    names: set[str] = set()
    for klass in cls.__mro__[:-1]:
        names.update(vars(klass), getattr(klass, "__annotations__", {}))
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            return None
        for node in ast.walk(tree):
            if _dynamic(node):
                return None
            if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and \
                    isinstance(node.value, ast.Name) and node.value.id == "self":
                names.add(node.attr)
    return names


def _dynamic(node: ast.AST) -> bool:
    """Whether ``node`` may give an instance attributes no ``self.NAME =`` shows."""
    return (isinstance(node, ast.Name) and node.id == "setattr") or \
        (isinstance(node, ast.Attribute) and node.attr in ("__dict__", "__setattr__")) or \
        (isinstance(node, ast.FunctionDef) and node.name == "__getattr__")


# -- the step on the tiny input ----------------------------------------------------------------------------------


def _check_function(fn: Callable, kind: str, args: tuple, functions: list[Callable]) -> None:
    """Compile ``fn`` on the tiny input where numba compiles (else run it) and check what it returns."""
    _check_signature(fn, kind)
    numba = _numba()
    if numba is None:
        returned = _run(fn, kind, args, functions)
        if returned is not UNCHECKED:
            _check_value(fn, kind, returned)
    else:
        _check_type(fn, kind, _compile(numba, fn, kind, args, functions))


def _check_signature(fn: Callable, kind: str) -> None:
    """The arguments the batch loop passes, by position: a step's five, ``tuned``'s four."""
    names = ("p", "s", "temp_q5", "target_c") + (("board",) if kind == "step" else ())
    try:
        inspect.signature(fn).bind(*names)
    except TypeError as exc:
        raise _Fault(f"its {kind} {fn.__name__} cannot take the batch's arguments ({', '.join(names)}): {exc}",
                     where=_def_line(fn)) from None


def _numba() -> Any:
    """numba where it compiles (installed, its JIT not disabled), else None."""
    try:
        import numba
    except ImportError:
        return None
    return None if numba.config.DISABLE_JIT else numba  # type: ignore[attr-defined]


def _probe(fn: Callable, kind: str, source: int) -> Callable:
    """``fn`` called as the batch loop calls it, on lane 0 of the records. ``source`` (never 0, so numba prunes
    the other branch) puts the law's source hash in numba's cache key: an edited law compiles afresh."""
    if kind == "step":
        def probe(p, s, board, temp_q5, target_c):
            return fn(p[0], s[0], temp_q5, target_c, board[0]) if source else 0
    else:
        def probe(p, s, board, temp_q5, target_c):
            return fn(p[0], s[0], temp_q5, target_c) if source else 0
    return probe


def _compile(numba: Any, fn: Callable, kind: str, args: tuple, functions: list[Callable]) -> Any:
    """The numba type ``fn`` returns, compiled for the tiny input's types (compiled only, not run)."""
    from numba.core.errors import NumbaError

    jitable(fn)
    probe = _probe(fn, kind, source_hash(*functions))
    try:  # cached where numba finds a folder for it: a law checked before is loaded, not compiled again
        dispatcher = numba.njit(cache=True, **NUMBA_OPTIONS)(probe)
    except RuntimeError:  # numba's "no locator available": compiled afresh each time
        dispatcher = numba.njit(**NUMBA_OPTIONS)(probe)
    try:
        dispatcher.compile(tuple(numba.typeof(a) for a in (*args, TEMP_Q5, TARGET_C)))
    except KeyError as exc:  # numba's typing of a record field the record lacks
        if not exc.args or not isinstance(exc.args[0], str):
            raise
        raise _Fault(_field_missing(exc.args[0], args), exc.args[0], details=str(exc)) from exc
    except NumbaError as exc:
        raise _numba_fault(str(exc), functions) from exc
    return dispatcher.nopython_signatures[0].return_type


def _run(fn: Callable, kind: str, args: tuple, functions: list[Callable]) -> object:
    """What ``fn`` returns on the tiny input as plain Python (warnings of numpy's zero divisions silenced), or
    ``UNCHECKED`` where its arithmetic fails: the tiny input's parameters are zeros, no lane's."""
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return _probe(fn, kind, source=1)(*args, TEMP_Q5, TARGET_C)  # plain Python keys no cache
    except ArithmeticError:
        return UNCHECKED
    except Exception as exc:
        raise _python_fault(exc, args, functions) from exc


def _field_missing(name: str, args: tuple) -> str:
    fields = "; ".join(f"{label}: {', '.join(a.dtype.names or ()) or 'none'}"
                       for label, a in zip(("params", "state", "board"), args))
    return f"its code reads or writes the record field {name!r}, which its records lack ({fields})"


def _check_type(fn: Callable, kind: str, returned: Any) -> None:
    """The compiled return type: one integer (a step), a bool or an integer (``tuned``)."""
    from numba.core import types

    if isinstance(returned, types.Integer) or (kind == "tuned" and isinstance(returned, types.Boolean)):
        return
    if isinstance(returned, types.BaseTuple):
        _wrong_return(fn, kind, f"{len(returned)} values", "tuple")
    if isinstance(returned, types.Optional):
        _wrong_return(fn, kind, "None on some path", "none")
    _wrong_return(fn, kind, f"a {returned}", "any")


def _check_value(fn: Callable, kind: str, returned: object) -> None:
    """The value a plain-Python run returned, checked as ``_check_type`` checks the compiled type."""
    if isinstance(returned, (bool, np.bool_)):
        if kind == "tuned":
            return
    elif isinstance(returned, (int, np.integer)):
        return
    if isinstance(returned, tuple):
        _wrong_return(fn, kind, f"{len(returned)} values", "tuple")
    if returned is None:
        _wrong_return(fn, kind, "None", "none")
    _wrong_return(fn, kind, f"a {type(returned).__name__}", "any")


def _wrong_return(fn: Callable, kind: str, what: str, shape: str) -> NoReturn:
    expected = "one integer 0..255" if kind == "step" else "one bool"
    raise _Fault(f"its {kind} {fn.__name__} returns {what}, not {expected}", where=_return_line(fn, shape))


def _return_line(fn: Callable, shape: str) -> tuple[str, int]:
    """The first ``return`` of ``fn`` of that shape (a tuple, None), else its ``def`` line."""
    def fits(node: ast.Return) -> bool:
        value = node.value
        if shape == "tuple":
            return isinstance(value, ast.Tuple)
        if shape == "none":
            return value is None or (isinstance(value, ast.Constant) and value.value is None)
        return True

    nodes = [n for n in _function_nodes(fn) if isinstance(n, ast.Return) and fits(n)]
    path, first = _def_line(fn)
    return (path, first + nodes[0].lineno - 1) if nodes else (path, first)


# -- where numba or Python located the fault ---------------------------------------------------------------------

# numba's locations: 'File "x.py", line 12:' and '... at /abs/x.py (12)', innermost first.
LOCATION = re.compile(r'File "(?P<a>[^"]+)", line (?P<b>\d+)|\bat (?P<c>/[^\n]+?) \((?P<d>\d+)\)')
# numba's messages, most telling first: a pattern, what it means ({name}, {detail}), and the groups of the two.
NUMBA_FAULTS = (
    (r"Unknown attribute '(\w+)' of type Record", "its code reads or writes the record field {name!r}, which its "
     "records lack", 1, 1),
    (r"The use of a (.+?) type, assigned to variable '(\w+)' in globals", "its code reads the global {name!r}, a "
     "{detail} numba cannot freeze in as a constant (use a number, a tuple or a numpy array)", 2, 1),
    (r"Untyped global name '(\w+)': (.+)", "its code reads the global {name!r}, which numba cannot type ({detail})",
     1, 2),
    (r"NameError: name '(\w+)' is not defined", "its code reads the name {name!r}, defined nowhere", 1, 1),
    (r"(NRT) required but not enabled", "its code builds a Python object (a list, a dict, a string or a new array), "
     "which the compiled batch cannot allocate", 0, 1),
    (r"Can't unify return type from the following types: (.+)", "its code returns different types on different "
     "paths ({detail})", 0, 1),
)


def _numba_fault(message: str, functions: list[Callable]) -> _Fault:
    """What numba's message says is wrong, the name involved, and the first place in the user's files."""
    where = _user_location(message, functions)
    for pattern, what, name_group, detail_group in NUMBA_FAULTS:
        found = re.search(pattern, message)
        if found:
            name = found.group(name_group) if name_group else None
            detail = found.group(detail_group).strip().rstrip(".")
            return _Fault(what.format(name=name, detail=detail), name, where, message)
    own = {fn.__name__ for fn in functions}
    for callee, signature in re.findall(r"No implementation of function Function\((.+?)\) found for signature:"
                                        r"\s*>>> (.+)", message):
        if not any(f"<function {name} at" in callee for name in own):
            return _Fault(f"its code calls {signature.strip()}, which numba does not compile", None, where, message)
    first = next((line.strip() for line in message.splitlines()[1:] if line.strip()), message)
    return _Fault(f"numba cannot compile its code: {first}", None, where, message)


def _user_location(message: str, functions: list[Callable]) -> tuple[str, int] | None:
    """The first (innermost) location in numba's message inside a file of the law's own functions."""
    files = {os.path.abspath(_source_file(fn)) for fn in functions}
    for found in LOCATION.finditer(message):
        path, line = (found["a"], found["b"]) if found["a"] else (found["c"], found["d"])
        if os.path.abspath(path) in files:
            return os.path.abspath(path), int(line)
    return None


def _python_fault(exc: Exception, args: tuple, functions: list[Callable]) -> _Fault:
    """What a plain-Python run raised, the name involved, and the innermost frame in the user's files."""
    files = {os.path.abspath(_source_file(fn)) for fn in functions}
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if os.path.abspath(f.filename) in files]
    where = (os.path.abspath(frames[-1].filename), frames[-1].lineno or 0) if frames else None
    details = "".join(traceback.format_exception(exc))
    if isinstance(exc, AttributeError) and "'record' object" in str(exc):
        name = re.search(r"attribute '(\w+)'", str(exc))
        field = name.group(1) if name else "?"
        return _Fault(_field_missing(field, args), field, where, details)
    if isinstance(exc, NameError) and exc.name:
        return _Fault(f"its code reads the name {exc.name!r}, defined nowhere", exc.name, where, details)
    return _Fault(f"its code raises {type(exc).__name__}: {exc}", None, where, details)


def _locate(name: str, functions: list[Callable]) -> tuple[str, int] | None:
    """The first line of the law's functions that reads or writes ``name`` (a field, a global)."""
    for fn in functions:
        path, first = _def_line(fn)
        for node in _function_nodes(fn):
            if (isinstance(node, ast.Attribute) and node.attr == name) or \
                    (isinstance(node, ast.Name) and node.id == name):
                return path, first + node.lineno - 1
    return None


def _function_nodes(fn: Callable) -> list[ast.stmt | ast.expr]:
    """The statements and expressions of ``fn``'s source, in source order (none where no source is kept)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError, SyntaxError):
        return []
    nodes = [n for n in ast.walk(tree) if isinstance(n, (ast.stmt, ast.expr))]
    return sorted(nodes, key=lambda n: (n.lineno, n.col_offset))


def _def_line(obj: Any) -> tuple[str, int]:
    """The file and first line of a function's or a class's source (line 0 where none is kept)."""
    try:
        return os.path.abspath(_source_file(obj)), inspect.getsourcelines(obj)[1]
    except (OSError, TypeError):
        return _source_file(obj), 0


def _source_file(obj: Any) -> str:
    try:
        return inspect.getsourcefile(obj) or inspect.getfile(obj)
    except TypeError:
        return "<unknown>"
