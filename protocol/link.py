"""The serial wire from host to printer: bytes arrive at the link's byte rate, in virtual time.

At 115200 baud, 8N1, a byte takes 10 bits: 11.52 bytes per millisecond. A host that writes a
burst (``M110 N0`` then numbered lines, without waiting for the ``ok``) does not land it in
Marlin's RX ring at once: each line finishes arriving a line's worth of byte times after the one
before, and an instant command (M110) runs in between, as on the board.

A write to an idle link has its first line there at once (its bytes were on the wire while the
host wrote them); the rest follows at the byte rate, and a later write queues behind what is
still in flight. ``in_flight`` is bounded by the caller, as a host OS's serial buffer bounds a
real writer: its write() blocks until the wire drains.
"""

from __future__ import annotations

import math
from collections import deque

from twin.clock import TICK_S

LINK_BAUD = 115200  # Marlin's default BAUDRATE (Configuration.h)
BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit
BYTE_TICKS = BITS_PER_BYTE / LINK_BAUD / TICK_S  # about 0.085 ticks (86.8 us) per byte
_EPS_TICKS = 1e-9  # float slack: a byte due exactly at a tick has arrived by it


def first_eol(data: bytes | bytearray, start: int = 0) -> int:
    """Index of the first CR or LF at or after ``start``, or -1."""
    found = [i for i in (data.find(b"\n", start), data.find(b"\r", start)) if i >= 0]
    return min(found) if found else -1


class SerialLink:
    """Bytes written by the host and not yet arrived: chunks with the tick their first byte started."""

    def __init__(self) -> None:
        self._chunks: deque[list] = deque()  # [start_tick, data, taken]: byte i arrives at start + (i+1) x BYTE_TICKS
        self._free_tick = -math.inf  # the tick the last byte written so far arrives
        self.in_flight = 0  # bytes written and not yet taken

    def __repr__(self) -> str:
        return f"SerialLink({self.in_flight} bytes in flight)"

    def clear(self) -> None:
        """A reset: what was on the wire is gone (the host reopens the port)."""
        self._chunks.clear()
        self._free_tick = -math.inf
        self.in_flight = 0

    def send(self, data: bytes, now_tick: int) -> None:
        """The host writes ``data`` at ``now_tick``."""
        if not data:
            return
        first_line = first_eol(data) + 1 or len(data)
        start = max(self._free_tick, now_tick - first_line * BYTE_TICKS)
        self._free_tick = start + len(data) * BYTE_TICKS
        self._chunks.append([start, bytes(data), 0])
        self.in_flight += len(data)

    def take(self, now_tick: int) -> bytes:
        """The bytes arrived by ``now_tick`` and not taken yet, in order."""
        parts = []
        while self._chunks:
            chunk = self._chunks[0]
            start, data, taken = chunk
            arrived = min(len(data), max(0, math.floor((now_tick - start) / BYTE_TICKS + _EPS_TICKS)))
            if arrived > taken:
                parts.append(data[taken:arrived])
                chunk[2] = arrived
            if arrived < len(data):
                break
            self._chunks.popleft()
        taken_bytes = b"".join(parts)
        self.in_flight -= len(taken_bytes)
        return taken_bytes

    def next_line_tick(self) -> int | None:
        """The tick by which the next end of line in flight has arrived, or None if none is."""
        for start, data, taken in self._chunks:
            eol = first_eol(data, taken)
            if eol >= 0:
                return math.ceil(start + (eol + 1) * BYTE_TICKS - _EPS_TICKS)
        return None

    def drained_tick(self, keep_bytes: int) -> int:
        """The tick by which no more than ``keep_bytes`` are still in flight (0: already so)."""
        need = self.in_flight - keep_bytes  # bytes that must arrive first
        for start, data, taken in self._chunks:
            if need <= 0:
                break
            if need <= len(data) - taken:
                return math.ceil(start + (taken + need) * BYTE_TICKS - _EPS_TICKS)
            need -= len(data) - taken
        return 0
