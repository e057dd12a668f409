"""The batch kernels' plant tables: a plant's exact tick maps for each kind of run, stacked by model.

A batch kernel steps a linear plant ``x[k+1] = Phi x[k] + g u[k] + H d`` over runs of ticks with a
piecewise constant heater input (twin/linear.py): the sensor at a run's sample offsets and the
state at its end are the free response ``Phi^s x`` plus the disturbance's response plus, for each
heater pulse [a, b), the step response ``S(s - a) - S(s - b)`` with ``S(k) = sum_{j<k} Phi^j g``.
This module builds those tables from ``Phi, g, H`` (the plant's own discretisation) by the same
recurrences as ``TickModel``, for M models at once: one for a linear plant, one per 0.5 C block bin
for a radiating plant (the scalar engine's relinearisation, twin/plants.py), each bin's ``Phi, g, H``
from the scalar engine's own ``TickModel`` of that bin's model.

A run kind is its length and its sample offsets. Tables are cached by content (the model's
matrices, the disturbances, the kinds): a tuner that replays one scenario pays for them once.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from firmware_port.marlin.constants import MIN_ADC_ISR_LOOPS, TICKS_PER_READING
from twin.linear import BLOCK, SENSOR, TickModel
from twin.plants import RADIATION_BIN_C

MAX_CACHED_TABLE_BYTES = 384 << 20  # stacked tables kept (LRU) up to this size of their arrays: every member
# of a log's ensemble (17 plants of a klippy.log, 68 tables, 139 MB) stays in hand from one generation to the next
MAX_CACHED_BINS = 4096  # one bin's discretisation, or its tables for one set of run kinds: a few KiB
MAX_SAMPLES = TICKS_PER_READING // MIN_ADC_ISR_LOOPS  # ADC samples in one Marlin control period
ROW_OFFSET = TICKS_PER_READING  # ``sample_rows``: pulse edges up to a whole period before the first sample


@dataclass(frozen=True)
class Tables:
    """Stacked over M models: px (M, kinds, n_x, J) and pdd (M, kinds, J): the sensor's free response
    at each kind's samples, bx and bdd the block's; fx (M, kinds, n_x, n_x), fdd (M, kinds, n_x): the
    state's at the run's end; steps (M, n_max + 1, n_x), sensor_steps and block_steps (M, n_max + 1):
    the heater's step responses; io (M, 3, n_x + 1): the one-tick response g, then the block and
    sensor output rows with their constant. ``bin_lo``: the first model's block bin (index of
    ``RADIATION_BIN_C`` steps)."""

    px: np.ndarray
    pdd: np.ndarray
    bx: np.ndarray
    bdd: np.ndarray
    fx: np.ndarray
    fdd: np.ndarray
    steps: np.ndarray
    sensor_steps: np.ndarray
    block_steps: np.ndarray
    io: np.ndarray
    bin_lo: int = 0

    @property
    def n_models(self) -> int:
        return self.px.shape[0]

    @functools.cached_property
    def sample_rows(self) -> np.ndarray:
        """(M, ROW_OFFSET + MIN_ADC_ISR_LOOPS, MAX_SAMPLES): row o + ROW_OFFSET holds
        ``sensor_steps[max(o + 10 j, 0)]`` for sample j, o = -ROW_OFFSET .. 9: a pulse's sensor step at
        every sample of a Marlin control period (samples 10 ticks apart; o = first sample - the pulse's
        edge), one row read per pulse in the kernel."""
        o = np.arange(-ROW_OFFSET, MIN_ADC_ISR_LOOPS)[:, None] + MIN_ADC_ISR_LOOPS * np.arange(MAX_SAMPLES)[None, :]
        return _frozen(self.sensor_steps[:, np.clip(o, 0, self.sensor_steps.shape[1] - 1)])  # S(0) = 0: before


    @functools.cached_property
    def chords(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """How far a Marlin period's samples can lie from the chord through its first and last, as the
        largest |value - chord| over the samples of: each state's free-response row (M, kinds, n_x),
        their sum (M, kinds), the disturbance's (M, kinds), each pulse edge's row of ``sample_rows``
        (M, rows). The maps are linear, so a sample strays from the chord by at most
        sum_dev |x_0| + sum_i x_dev_i |x_i - x_0| + d_dev + the pulses' (writing x = x_0 + (x - x_0):
        a plant's states sit near one another, and a state vector of equal temperatures moves
        almost along the chord). When that band lies inside one ADC count the kernel needs no sample
        in between. Only full periods (MAX_SAMPLES samples) may take the shortcut: the kernel checks."""
        t = np.arange(MAX_SAMPLES) / (MAX_SAMPLES - 1)

        def off_chord(rows: np.ndarray) -> np.ndarray:
            chord = (1.0 - t) * rows[..., :1] + t * rows[..., MAX_SAMPLES - 1:MAX_SAMPLES]
            return np.max(np.abs(rows[..., :MAX_SAMPLES] - chord), axis=-1)

        rows_dev = _frozen(off_chord(self.sample_rows))
        if self.px.shape[3] < MAX_SAMPLES:  # no full period among the kinds
            return (_frozen(np.full(self.px.shape[:3], np.inf)), _frozen(np.full(self.pdd.shape[:2], np.inf)),
                    _frozen(np.full(self.pdd.shape[:2], np.inf)), rows_dev)
        return (_frozen(off_chord(self.px)), _frozen(off_chord(self.px.sum(axis=2))), _frozen(off_chord(self.pdd)),
                rows_dev)


def _key(*arrays: np.ndarray) -> tuple:
    return tuple((a.shape, a.tobytes()) for a in arrays)


_CACHE: OrderedDict[tuple, Tables] = OrderedDict()


def _nbytes(tables: Tables) -> int:
    return sum(a.nbytes for a in (tables.px, tables.pdd, tables.bx, tables.bdd, tables.fx, tables.fdd, tables.steps,
                                  tables.sensor_steps, tables.block_steps, tables.io))


def _cached(key: tuple, build) -> Tables:
    """The tables of ``key``, built once; the least recently used dropped while the cache's arrays exceed
    MAX_CACHED_TABLE_BYTES (the newest always kept)."""
    tables = _CACHE.get(key)
    if tables is None:
        tables = _CACHE[key] = build()
        total = sum(_nbytes(t) for t in _CACHE.values())
        while total > MAX_CACHED_TABLE_BYTES and len(_CACHE) > 1:
            total -= _nbytes(_CACHE.popitem(last=False)[1])
    else:
        _CACHE.move_to_end(key)
    return tables


def linear_tables(model: TickModel, d: np.ndarray, kinds: tuple, n_max: int) -> Tables:
    """One model's tables (M = 1), from its own discretisation."""
    lti = model.lti
    arrays = (model.phi[None], model.g[None], model.h[None], lti.c, lti.f, np.asarray(d, float))
    return _cached(("linear", kinds, n_max, *_key(*arrays)), lambda: stack(*arrays, kinds, n_max))


def bin_tables(plant, d: np.ndarray, kinds: tuple, n_max: int, bin_lo: int, bin_hi: int) -> Tables:
    """A radiating plant's tables for block bins bin_lo..bin_hi (in RADIATION_BIN_C steps) under its
    current fan, flow and ambient: each bin's model as the scalar engine linearises it there. Bins are
    built once each (a tune visits the same ones again and again) and stacked per range."""
    spec, fan, flow, ambient = plant.spec, plant.fan, plant.flow_mm_s, plant.ambient_c
    d = np.asarray(d, float)
    where = (spec, fan, flow, ambient, d.tobytes(), kinds, n_max)

    def build() -> Tables:
        missing = [k for k in range(bin_lo, bin_hi + 1) if (*where, k) not in _BINS]
        if missing:
            models = [_bin_model(spec, fan, flow, ambient, k) for k in missing]
            lti = models[0].lti
            built = stack(np.array([m.phi for m in models]), np.array([m.g for m in models]),
                          np.array([m.h for m in models]), lti.c, lti.f, d, kinds, n_max)
            for i, k in enumerate(missing):
                _BINS[(*where, k)] = _tables({f: getattr(built, f)[i:i + 1] for f in _ARRAYS})
        parts = []
        for k in range(bin_lo, bin_hi + 1):
            _BINS.move_to_end((*where, k))
            parts.append(_BINS[(*where, k)])
        while len(_BINS) > MAX_CACHED_BINS:  # only once this range's bins are all in hand
            _BINS.popitem(last=False)
        stacked = {f: _frozen(np.concatenate([getattr(t, f) for t in parts])) for f in _ARRAYS}
        return _tables(stacked, bin_lo)

    return _cached(("bins", *where, bin_lo, bin_hi), build)


_ARRAYS = ("px", "pdd", "bx", "bdd", "fx", "fdd", "steps", "sensor_steps", "block_steps", "io")
_BINS: OrderedDict[tuple, Tables] = OrderedDict()


@functools.lru_cache(maxsize=MAX_CACHED_BINS)
def _bin_model(spec, fan: float, flow_mm_s: float, ambient_c: float, bin_index: int) -> TickModel:
    """The scalar engine's discretisation of the model linearised at block bin ``bin_index``."""
    return TickModel(spec.lti(spec.conditions(fan, flow_mm_s, ambient_c, bin_index * RADIATION_BIN_C)))


def block_bin(block_c: float) -> int:
    """The bin the scalar engine linearises at: round(block_c / RADIATION_BIN_C), halves to even."""
    return int(np.rint(block_c / RADIATION_BIN_C))


def stack(phi: np.ndarray, g: np.ndarray, h: np.ndarray, c: np.ndarray, f: np.ndarray, d: np.ndarray,
          kinds: tuple, n_max: int) -> Tables:
    """Tables of M models (phi (M, n, n), g (M, n), h (M, n, m); c, f, d shared) for run kinds
    ((n_ticks, offsets), ...) and step tables up to n_max ticks. ``TickModel``'s recurrences:
    Phi^(k+1) = Phi Phi^k, S(k+1) = S(k) + Phi^k g, D(k+1) = D(k) + Phi^k H."""
    n_models, n_x = g.shape
    need = max(n_max, *(n for n, _ in kinds), *(max(offs, default=0) for _, offs in kinds))
    powers = [np.broadcast_to(np.eye(n_x), (n_models, n_x, n_x))]
    u_resp, d_resp = [np.zeros((n_models, n_x))], [np.zeros_like(h)]
    for _ in range(need):
        p = powers[-1]
        u_resp.append(u_resp[-1] + (p @ g[..., None])[..., 0])
        d_resp.append(d_resp[-1] + p @ h)
        powers.append(phi @ p)
    j_max = max(1, *(len(offs) for _, offs in kinds))
    out: dict[str, np.ndarray] = {name: np.zeros((n_models, len(kinds), n_x, j_max)) for name in ("px", "bx")}
    out |= {name: np.zeros((n_models, len(kinds), j_max)) for name in ("pdd", "bdd")}
    fx, fdd = np.zeros((n_models, len(kinds), n_x, n_x)), np.zeros((n_models, len(kinds), n_x))
    for k, (n, offsets) in enumerate(kinds):
        for j, s in enumerate(offsets):
            for row, x_map, d_map in ((SENSOR, "px", "pdd"), (BLOCK, "bx", "bdd")):
                out[x_map][:, k, :, j] = c[row] @ powers[s]
                out[d_map][:, k, j] = (c[row] @ d_resp[s] + f[row]) @ d
        fx[:, k], fdd[:, k] = powers[n], d_resp[n] @ d
    steps = np.stack(u_resp[: n_max + 1], axis=1)  # (M, n_max + 1, n_x)
    out_d = f @ d
    io = np.zeros((n_models, 3, n_x + 1))
    io[:, 0, :n_x] = g
    io[:, 1, :n_x], io[:, 1, n_x] = c[BLOCK], out_d[BLOCK]
    io[:, 2, :n_x], io[:, 2, n_x] = c[SENSOR], out_d[SENSOR]
    out |= {"fx": fx, "fdd": fdd, "steps": steps, "sensor_steps": steps @ c[SENSOR], "block_steps": steps @ c[BLOCK],
            "io": io}
    return _tables({name: _frozen(array) for name, array in out.items()})


def _tables(arrays: dict[str, np.ndarray], bin_lo: int = 0) -> Tables:
    return Tables(arrays["px"], arrays["pdd"], arrays["bx"], arrays["bdd"], arrays["fx"], arrays["fdd"],
                  arrays["steps"], arrays["sensor_steps"], arrays["block_steps"], arrays["io"], bin_lo)


def _frozen(array: np.ndarray) -> np.ndarray:
    """Read-only: cached tables are shared, and the kernels take every table read-only (one compiled
    signature: numba types a read-only array apart from a writable one)."""
    array.flags.writeable = False
    return array
