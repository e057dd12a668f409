"""Which controller family a tune runs: a firmware build's name, or a user's ``module:attribute``.

A firmware build (firmware_port/firmwares.py ``PARAM_SPACES``) gives the space of the heater it
runs on (the bed's defaults differ from the hotend's); so does a host's control (``HOST_SPACES``:
Kalico's MPC, on the kalico loop). A user's ``module:attribute``, importable
from the current directory or the Python path (e.g. ``--controller my_smith:SPACE``), names either
a ``ParamSpace``, or a function defined in that module whose one parameter is named ``heater``
(it gets "hotend" or "bed" and returns a ParamSpace). Nothing else is ever called: the attribute is
checked before, so ``os:system`` or ``subprocess:run`` is refused, not run. The module's name must be dotted
identifiers, each level found as a file before it is imported (not one built into Python), and sys.path is
left as it was.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import sys
from pathlib import Path
from types import ModuleType

from firmware_port.firmwares import HOST_SPACES, PARAM_SPACES, param_space
from firmware_port.params import ParamSpace
from twin.limits import UserError


def controller_names() -> list[str]:
    """The firmware builds with parameters to tune, then the host controls (Kalico's MPC)."""
    return list(PARAM_SPACES) + list(HOST_SPACES)


def resolve_controller(name: str, heater: str) -> ParamSpace:
    """The controller family ``name`` on ``heater``; UserError in one line for anything else."""
    if ":" not in name:
        try:
            return param_space(name, heater)
        except ValueError as exc:
            raise UserError(f"--controller {name}: {exc}") from None
    module_name, _, attribute = name.partition(":")
    try:
        found = getattr(_user_module(module_name), attribute)
    except (ImportError, AttributeError, ValueError, SyntaxError) as exc:
        raise UserError(f"--controller {name}: {exc}") from None
    if isinstance(found, ParamSpace):
        return found
    if not _space_function(found, module_name):
        raise UserError(f"--controller {name}: not a ParamSpace, nor a function of {module_name} with one "
                        "parameter named heater")
    try:
        space = found(heater)
    except (TypeError, ValueError) as exc:
        raise UserError(f"--controller {name}({heater!r}): {exc}") from None
    if not isinstance(space, ParamSpace):
        raise UserError(f"--controller {name}({heater!r}): returned {type(space).__name__}, not a ParamSpace")
    return space


def _user_module(module_name: str) -> ModuleType:
    """``module_name`` imported from the current directory or the Python path, each level found as a file
    before it is imported; sys.path as it was afterwards. ValueError for a name that is not dotted
    identifiers (``..``, ``a b``), ImportError for one not found or built into Python (``sys``)."""
    if not all(part.isidentifier() for part in module_name.split(".")):
        raise ValueError(f"{module_name!r} is not a module name (dotted identifiers)")
    saved = list(sys.path)
    sys.path.insert(0, str(Path.cwd()))
    try:
        parts = module_name.split(".")
        for depth in range(1, len(parts) + 1):
            spec = importlib.util.find_spec(".".join(parts[:depth]))
            if spec is None:  # importlib's finders skip what is not a regular file (a FIFO would block)
                raise ImportError(f"no module named {'.'.join(parts[:depth])!r}")
            if not spec.has_location:
                raise ImportError(f"{spec.name!r} is built into Python, not a module file")
        return importlib.import_module(module_name)
    finally:
        sys.path[:] = saved


def _space_function(found: object, module_name: str) -> bool:
    """Whether ``found`` is a plain Python function defined in ``module_name`` taking exactly one
    parameter, ``heater``: the only callable a ``module:attribute`` may name."""
    if not inspect.isfunction(found) or found.__module__ != module_name:
        return False
    parameters = list(inspect.signature(found).parameters.values())
    return len(parameters) == 1 and parameters[0].name == "heater" and \
        parameters[0].kind in (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
