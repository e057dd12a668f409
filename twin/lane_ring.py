"""A dead time on the numpy lanes: each lane's ring of past heater pulses, as ``batch_kernel``'s ``_ring_*``.

The plant sees the soft PWM's pulses ``delay`` ticks late (exact on the tick grid). Every lane keeps its
pulses (absolute ticks [start, end), a pulse that continues the last one merged into it) in its row of
``ring`` (N, cap, 2), from ``head`` for ``length`` slots (``state``: (N, 2) head, length): the arrays the
compiled loop keeps, updated here on all lanes at once, so the plant's sums see the same pulses in the same
order (a lane with fewer pulses pads with empty ones, which add exactly 0.0) and either path can take over.
"""

from __future__ import annotations

import numpy as np


def push(ring: np.ndarray, state: np.ndarray, start: np.ndarray, end: np.ndarray) -> None:
    """Append each lane's pulse [start, end) (absolute ticks; none where end <= start), merged with the
    lane's last pulse where it continues it (``_ring_push``)."""
    cap, lanes = ring.shape[1], np.arange(len(ring))
    start, end = np.broadcast_to(start, lanes.shape), np.broadcast_to(end, lanes.shape)
    head, length = state[:, 0], state[:, 1]
    last = (head + length - 1) % cap
    pulse = end > start
    merge = pulse & (length > 0) & (ring[lanes, last, 1] == start)
    ring[lanes[merge], last[merge], 1] = end[merge]
    added = pulse & ~merge
    slot = (head + length) % cap
    ring[lanes[added], slot[added]] = np.column_stack((start[added], end[added]))
    state[:, 1] += added


def delayed(ring: np.ndarray, state: np.ndarray, tick: int, n_ticks: int, delay: int) -> list[tuple]:
    """The pulses the plant sees over ticks [tick, tick + n_ticks), relative to ``tick`` and cut to the run:
    a list of per-lane (alpha, beta) pairs, empty where a lane has fewer (``_ring_delayed``); pulses that
    ended before the run leave the ring."""
    cap, lanes = ring.shape[1], np.arange(len(ring))
    while True:
        gone = (state[:, 1] > 0) & (ring[lanes, state[:, 0], 1] + delay <= tick)
        if not gone.any():
            break
        state[gone, 0] = (state[gone, 0] + 1) % cap
        state[gone, 1] -= 1
    pulses = []
    for i in range(int(state[:, 1].max(initial=0))):
        slot = (state[:, 0] + i) % cap
        start = ring[lanes, slot, 0] + delay - tick
        seen = (i < state[:, 1]) & (start < n_ticks)  # pulses start in order: a late one ends the lane's list
        if not seen.any():
            break
        alpha = np.where(seen, np.maximum(start, 0), 0)
        pulses.append((alpha, np.where(seen, np.minimum(ring[lanes, slot, 1] + delay - tick, n_ticks), 0)))
    return pulses


def cut_last(ring: np.ndarray, state: np.ndarray, cut: np.ndarray) -> None:
    """Where ``cut``: the main loop switched the pin off for the period's last tick, so the lane's last pulse
    ends a tick early, and leaves the ring if that empties it (``_ring_cut_last``)."""
    cap = ring.shape[1]
    lanes = np.flatnonzero(cut)
    last = (state[lanes, 0] + state[lanes, 1] - 1) % cap
    ring[lanes, last, 1] -= 1
    state[lanes[ring[lanes, last, 1] <= ring[lanes, last, 0]], 1] -= 1
