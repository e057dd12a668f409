"""The seed papers' modules by id: each has ``report(budget, progress)`` and ``steps(budget)``. A module is
imported when its id is first looked up (its experiments import scipy and the tuning layer), so that
``python -m tools.seeds --help`` lists the ids without paying for them."""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from types import ModuleType

SEED_IDS = ("000", "001", "002", "003", "004")  # tools/seeds/seed<ID>.py


class _Papers(Mapping[str, ModuleType]):
    """``PAPERS[id]``: the module tools.seeds.seed<id>, imported on first use."""

    def __getitem__(self, seed: str) -> ModuleType:
        if seed not in SEED_IDS:
            raise KeyError(seed)
        return importlib.import_module(f"tools.seeds.seed{seed}")

    def __iter__(self) -> Iterator[str]:
        return iter(SEED_IDS)

    def __len__(self) -> int:
        return len(SEED_IDS)

    def __repr__(self) -> str:
        return f"PAPERS({', '.join(SEED_IDS)})"


PAPERS: Mapping[str, ModuleType] = _Papers()
