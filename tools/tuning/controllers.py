"""Which controller family a tune runs: a firmware build's name, or a user's ``module:attribute``.

A firmware build (firmware_port/firmwares.py ``PARAM_SPACES``) gives the space of the heater it
runs on (the bed's defaults differ from the hotend's). A user's ``module:attribute`` names a
``ParamSpace`` or a function of the heater ("hotend" or "bed") that returns one, importable from
the current directory or the Python path, e.g. ``--controller my_smith:SPACE``.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from firmware_port.firmwares import PARAM_SPACES, param_space
from firmware_port.params import ParamSpace


def controller_names() -> list[str]:
    """The firmware builds with parameters to tune."""
    return list(PARAM_SPACES)


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
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"--controller {name}: {exc}") from None
    try:
        space = found if isinstance(found, ParamSpace) else found(heater) if callable(found) else None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--controller {name}({heater!r}): {exc}") from None
    if not isinstance(space, ParamSpace):
        raise ValueError(f"--controller {name}: not a ParamSpace nor a function of the heater returning one")
    return space
