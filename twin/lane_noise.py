"""ADC noise for batch lanes: each lane's level, and the seeded normal stream it scales.

Common random numbers: lanes that name the same seed share one stream, ``SeedSequence(seed).spawn``'s
first (``twin.sensor.seeded_chains``), the one a scalar twin's first heater draws (``Twin``'s hotend
chain, ``KlipperTwin``'s first heater). A lane with seed s and noise n adds n times that stream's
normals, in order, to its conversions: what that scalar twin reads.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from twin.limits import NOISE_MAX_LSB, checked_seed
from twin.sensor import seeded_chains


def per_lane(value, n: int, name: str, dtype) -> np.ndarray:
    """One value for every lane, or one per lane, as an (n,) array; ValueError names ``name``."""
    try:
        array = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}={value!r}: expected a number, or one per lane") from None
    if array.ndim == 0:
        return np.full(n, array, dtype=dtype)
    if array.shape != (n,):
        raise ValueError(f"{name}: one value, or one per lane ({n}), not {array.shape[0]}")
    return array


def noise_levels(noise_lsb: float | Sequence[float], n: int) -> np.ndarray:
    """Each lane's noise in LSB (n,); ValueError unless every one is finite and >= 0."""
    levels = per_lane(noise_lsb, n, "noise_lsb", float)
    if not np.all(np.isfinite(levels) & (levels >= 0) & (levels <= NOISE_MAX_LSB)):
        raise ValueError(f"noise_lsb: each lane's must be a finite number in 0..{NOISE_MAX_LSB:g} LSB")
    return levels


def seed_streams(seed: int | Sequence[int], n: int) -> tuple[np.ndarray, list[np.random.Generator]]:
    """Each lane's stream (n,), an index into one generator per distinct seed (in ascending order)."""
    for each in np.ravel(seed).tolist():
        checked_seed("seed", each)
    unique, streams = np.unique(per_lane(seed, n, "seed", np.int64), return_inverse=True)
    return streams, [seeded_chains(1, int(s))[0].rng for s in unique]


def draw(generators: Sequence[np.random.Generator], n_samples: int) -> np.ndarray:
    """The next n_samples normals of every stream, (streams, n_samples); a period without a sample (it ends
    before the ADC's next conversion) draws (streams, 0)."""
    return np.array([g.standard_normal(n_samples) for g in generators]).reshape(len(generators), n_samples)
