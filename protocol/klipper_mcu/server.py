"""The twin MCU on a pseudo-terminal, its clock paced by the wall clock.

The MCU's clock runs at ``speed`` x real time: its chip's ``clock_freq * speed`` ticks per wall
second, counted from the moment the pty was made. A reader thread stamps the host's bytes with the
wall clock as they arrive, and the MCU takes each chunk at its stamp: a stall of the serving loop (or
of the heavy imports before it starts) is not a late host. The loop sleeps until the MCU's next
timer or the host's next bytes, then runs the MCU up to the clock the wall says it is now; each
timer still runs at its own clock (mcu.py). As a USB board, the MCU is not reset when a host
opens the port (klippy resets it with the ``reset`` command); output nobody holds the port for
is dropped, as a USB link down loses it.

The pty exists from construction (``path``, ``link``); the MCU comes later, to ``serve_forever``:
a server can print its port before it imports the twin, and a host that opens it meanwhile has
its bytes kept, stamped.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
from collections import deque
from collections.abc import Callable

from protocol.klipper_mcu.mcu import KlipperMcu
from protocol.pty import Pty

MAX_WAIT_S = 0.5  # the loop looks at the wall at least this often, even with no timer pending
FLUSH_WAIT_S = 0.005  # output the pty did not take yet is retried this often
READ_POLL_MS = 100  # the reader looks for close() this often


class McuServer:
    """One MCU on a pty (``path``, and ``link`` if given); ``serve_forever(mcu)`` until interrupted."""

    def __init__(self, speed: float = 1.0, *, link: str | None = None, clock: Callable[[], float] = time.monotonic):
        if not speed > 0:
            raise ValueError(f"speed must be above 0, not {speed!r}")
        self.speed, self.clock = speed, clock
        self._pty = Pty(link)
        self._start_s = clock()
        self.path, self.link = self._pty.path, self._pty.link
        self._arrived = threading.Condition()
        self._events: deque[tuple[float, bytes | int]] = deque()  # (wall s since start, bytes or a change of holders)
        self._holders = 0
        self._unsent = bytearray()
        self._closing = threading.Event()
        self._reader = threading.Thread(target=self._read_loop, name="twin-mcu-reader", daemon=True)
        self._reader.start()

    def __repr__(self) -> str:
        return f"McuServer({self.address}, speed {self.speed:g}, {self._holders} holders)"

    @property
    def address(self) -> str:
        return self.link or self.path

    def world_clock(self, mcu: KlipperMcu, wall_s: float | None = None) -> int:
        """The MCU world clock the wall says it is now (or was at ``wall_s`` since the start)."""
        if wall_s is None:
            wall_s = self.clock() - self._start_s
        return int(wall_s * self.speed * mcu.chip.clock_freq)

    def serve_forever(self, mcu: KlipperMcu) -> None:
        while True:
            self.serve_once(mcu)

    def serve_once(self, mcu: KlipperMcu) -> None:
        """Wait for the MCU's next timer or the host; then the host's bytes at their stamps, the
        MCU's timers up to now, and its output to the host."""
        due = mcu.next_timer()
        wait_s = MAX_WAIT_S if due is None else (due - self.world_clock(mcu)) / (mcu.chip.clock_freq * self.speed)
        if self._unsent and self._holders:
            wait_s = min(wait_s, FLUSH_WAIT_S)
        with self._arrived:
            if not self._events and wait_s > 0:
                self._arrived.wait(min(wait_s, MAX_WAIT_S))
            events = list(self._events)
            self._events.clear()
            now = self.world_clock(mcu)  # under the lock: every chunk stamped before now is in events
        for wall_s, item in events:
            if isinstance(item, int):
                self._holders += item
                if not self._holders:
                    self._unsent.clear()
            else:
                mcu.receive(item, self.world_clock(mcu, wall_s))
        mcu.run_until(now)
        output = mcu.take_output()
        if self._holders:
            self._unsent += output
            self._flush()

    def close(self) -> None:
        self._closing.set()
        self._reader.join()
        self._pty.close()

    def __enter__(self) -> McuServer:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _push(self, item: bytes | int) -> None:
        with self._arrived:
            self._events.append((self.clock() - self._start_s, item))
            self._arrived.notify()

    def _read_loop(self) -> None:
        """The reader thread: who holds the port, and what the host sends, each stamped as it comes."""
        watch, master = self._pty.watch, self._pty.master
        poller = select.poll()
        poller.register(watch.fd, select.POLLIN)
        holders = 0
        while not self._closing.is_set():
            events = dict(poller.poll(READ_POLL_MS))
            if watch.fd in events:  # first: after a close and a reopen, the data is the new host's
                for change in watch.changes():
                    holders += change
                    if change > 0 and holders == 1:
                        poller.register(master, select.POLLIN)
                    elif change < 0 and holders == 0:
                        self._read_chunks()  # the last bytes it sent are still there
                        poller.unregister(master)
                    self._push(change)
            elif holders and events.get(master, 0) & (select.POLLIN | select.POLLHUP | select.POLLERR):
                self._read_chunks()

    def _read_chunks(self) -> None:
        for data in self._pty.chunks():
            self._push(data)

    def _flush(self) -> None:
        try:
            written = os.write(self._pty.master, self._unsent)
        except BlockingIOError:
            return  # the pty is full: retried soon
        except OSError as exc:
            if exc.errno == errno.EIO:
                return  # nobody holds the port any more (the reader will say so)
            raise
        del self._unsent[:written]
