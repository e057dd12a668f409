"""Which controller family a tune runs: a firmware build's name, or a user's ``module:attribute``.

A firmware build (firmware_port/firmwares.py ``PARAM_SPACES``) gives the space of the heater it
runs on (the bed's defaults differ from the hotend's); so does a host's control (``HOST_SPACES``:
Kalico's MPC, on the kalico loop). A user's ``module:attribute``, importable
from the current directory or the Python path (e.g. ``--controller my_smith:SPACE``), names either
a ``ParamSpace``, or a function defined in that module whose one parameter is named ``heater``
(it gets "hotend" or "bed" and returns a ParamSpace). Nothing else is ever called: the attribute is
checked before, so ``os:system`` or ``subprocess:run`` is refused, not run.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path

from firmware_port.firmwares import HOST_SPACES, PARAM_SPACES, param_space
from firmware_port.params import ParamSpace


def controller_names() -> list[str]:
    """The firmware builds with parameters to tune, then the host controls (Kalico's MPC)."""
    return list(PARAM_SPACES) + list(HOST_SPACES)


def resolve_controller(name: str, heater: str) -> ParamSpace:
    """The controller family ``name`` on ``heater``; ValueError in one line for anything else."""
    if ":" not in name:
        try:
            return param_space(name, heater)
        except ValueError as exc:
            raise ValueError(f"--controller {name}: {exc}") from None
    module_name, _, attribute = name.partition(":")
    if str(Path.cwd()) not in sys.path:
        sys.path.insert(0, str(Path.cwd()))
    try:
        found = getattr(importlib.import_module(module_name), attribute)
    except (ImportError, AttributeError, ValueError, SyntaxError) as exc:  # ValueError: an empty module name
        raise ValueError(f"--controller {name}: {exc}") from None
    if isinstance(found, ParamSpace):
        return found
    if not _space_function(found, module_name):
        raise ValueError(f"--controller {name}: not a ParamSpace, nor a function of {module_name} with one "
                         "parameter named heater")
    try:
        space = found(heater)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--controller {name}({heater!r}): {exc}") from None
    if not isinstance(space, ParamSpace):
        raise ValueError(f"--controller {name}({heater!r}): returned {type(space).__name__}, not a ParamSpace")
    return space


def _space_function(found: object, module_name: str) -> bool:
    """Whether ``found`` is a plain Python function defined in ``module_name`` taking exactly one
    parameter, ``heater``: the only callable a ``module:attribute`` may name."""
    if not inspect.isfunction(found) or found.__module__ != module_name:
        return False
    parameters = list(inspect.signature(found).parameters.values())
    return len(parameters) == 1 and parameters[0].name == "heater" and \
        parameters[0].kind in (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
