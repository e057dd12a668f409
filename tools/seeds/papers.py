"""The seed papers' modules by id: each has ``report(budget, progress)`` and ``steps(budget)``."""

from __future__ import annotations

from types import ModuleType

from tools.seeds import seed000, seed001, seed002, seed003, seed004

PAPERS: dict[str, ModuleType] = {"000": seed000, "001": seed001, "002": seed002, "003": seed003, "004": seed004}
