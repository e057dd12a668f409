"""The twin MCU on a pseudo-terminal, its clock paced by the wall clock.

The MCU's clock runs at ``speed`` x real time: ``CLOCK_FREQ * speed`` ticks per wall second. The
loop sleeps until the MCU's next timer or the host's next bytes, then runs the MCU up to the
clock the wall says it is now; each timer still runs at its own clock (mcu.py). As a USB board,
the MCU is not reset when a host opens the port (klippy resets it with the ``reset`` command);
output nobody holds the port for is dropped, as a USB link down loses it.
"""

from __future__ import annotations

import os
import select
import time
from collections.abc import Callable

from protocol.klipper_mcu.dictionary import CLOCK_FREQ
from protocol.klipper_mcu.mcu import KlipperMcu
from protocol.pty_server import Pty
from protocol.server import poll_ms

MAX_WAIT_S = 0.5  # the loop looks at the wall at least this often, even with no timer pending


class McuServer:
    """One MCU on a pty (``path``, and ``link`` if given); ``serve_forever`` until interrupted."""

    def __init__(self, mcu: KlipperMcu, speed: float = 1.0, *, link: str | None = None,
                 clock: Callable[[], float] = time.monotonic):
        if not speed > 0:
            raise ValueError(f"speed must be above 0, not {speed!r}")
        self.mcu, self.speed, self.clock = mcu, speed, clock
        self._start_s = clock()
        self._pty = Pty(link)
        self.path, self.link = self._pty.path, self._pty.link
        self._master = self._pty.master
        self._watch = self._pty.watch
        self._poller = select.poll()
        self._poller.register(self._watch.fd, select.POLLIN)
        self._holders = 0
        self._unsent = bytearray()

    def __repr__(self) -> str:
        return f"McuServer({self.address}, speed {self.speed:g}, {self.mcu!r})"

    @property
    def address(self) -> str:
        return self.link or self.path

    def world_clock(self) -> int:
        """The MCU world clock the wall says it is now."""
        return int((self.clock() - self._start_s) * self.speed * CLOCK_FREQ)

    def serve_forever(self) -> None:
        while True:
            self.serve_once()

    def serve_once(self) -> None:
        """Run the MCU to now, send its output, then wait for its next timer or the host."""
        now = self.world_clock()
        self.mcu.run_until(now)
        output = self.mcu.take_output()
        if self._holders:
            self._unsent += output
            self._flush()
        due = self.mcu.next_timer()
        wait_s = MAX_WAIT_S if due is None else min(MAX_WAIT_S, (due - now) / (CLOCK_FREQ * self.speed))
        if self._holders:
            self._poller.modify(self._master, select.POLLIN | (select.POLLOUT if self._unsent else 0))
        events = dict(self._poller.poll(poll_ms(wait_s)))
        if self._watch.fd in events:
            for change in self._watch.changes():
                self._holders += change
                if change > 0 and self._holders == 1:
                    self._poller.register(self._master, select.POLLIN)
                elif change < 0 and self._holders == 0:
                    self._read()
                    self._poller.unregister(self._master)
                    self._unsent.clear()
        revents = events.get(self._master, 0) if self._holders else 0
        if revents & select.POLLOUT:
            self._flush()
        if revents & (select.POLLIN | select.POLLHUP | select.POLLERR):
            self._read()

    def close(self) -> None:
        self._pty.close()

    def __enter__(self) -> McuServer:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def _read(self) -> None:
        for data in self._pty.chunks():
            self.mcu.receive(data, self.world_clock())
            self._unsent += self.mcu.take_output()
            self._flush()

    def _flush(self) -> None:
        if not self._unsent or not self._holders:
            return
        try:
            written = os.write(self._master, self._unsent)
        except BlockingIOError:
            return
        del self._unsent[:written]
