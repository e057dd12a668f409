"""One printer served to one host at a time over a file descriptor: what the pty and TCP servers share.

One thread and one poll() loop: bytes from the host go to the printer, the printer's virtual
clock advances as the pacer says, its output goes back. A host opening the port (pty) or
connecting (TCP) resets the board, as a USB printer's DTR auto-reset does, so every connection
starts with Marlin's ``start`` banner; output nobody is connected to read is dropped. There is no
thread: a command that runs at ``max`` is served a virtual second at a time, so the host's input
(M108) and the printer's output flow while it runs.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod

from protocol.corruption import RxCorruptor
from protocol.pacing import Pacer
from protocol.printer import VirtualPrinter
from protocol.pty import READ_SIZE  # noqa: F401  (one read size for every transport: tcp_server reads it here)
from protocol.transcript import Transcript

BOOT_DELAY_S = 0.2  # host connects -> board reset, unless its first bytes come sooner (a bootloader: ~1 s)
HOST_BUFFER_BYTES = 4096  # output a host may leave unread before Marlin's writes block (Linux N_TTY_BUF_SIZE)


class Server(ABC):
    """Serves one printer to one host at a time; subclasses own the file descriptors.

    A host's arrival resets the board when its first bytes come, or BOOT_DELAY_S after it
    connected for a host that waits for ``start`` (sooner, its own open() could discard the
    banner: pyserial flushes its input when it opens a port). Output the host has not taken
    yet stops the printer's clock until it drains, as Marlin waits on a full TX buffer.
    """

    def __init__(self, printer: VirtualPrinter, pacer: Pacer | None, transcript: Transcript | None,
                 corruptor: RxCorruptor | None):
        self.printer = printer
        self.pacer = pacer if pacer is not None else Pacer(printer)
        self.transcript = transcript
        self.corruptor = corruptor
        self._unsent = bytearray()
        self._connected_at: float | None = None  # monotonic time a host came, until its reset
        self._ready = False  # a host is there and its board was reset: output goes to it

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.address}, {self.printer!r})"

    def serve_forever(self) -> None:
        """Serve until interrupted (KeyboardInterrupt, or SystemExit from a SIGTERM handler)."""
        while True:
            self._note_tx()
            wait_s = None if self._unsent else self.pacer.advance()
            output = self.printer.take_output()
            if self._ready:
                self._unsent += output
                self._flush()
            if self._connected_at is not None:
                boot_left_s = self._connected_at + BOOT_DELAY_S - time.monotonic()
                if boot_left_s <= 0:
                    self._reset_for_host()
                    continue
                wait_s = boot_left_s if wait_s is None else min(wait_s, boot_left_s)
            self._wait(wait_s)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # -- what subclasses provide --------------------------------------------------------------
    @property
    @abstractmethod
    def address(self) -> str:
        """Where a host connects: the pty's path, or HOST:PORT."""

    @abstractmethod
    def close(self) -> None:
        """Release the port (fds, link)."""

    @abstractmethod
    def _write(self, data: bytes | bytearray) -> int:
        """Write without blocking; the count written (BlockingIOError when none fits)."""

    @abstractmethod
    def _wait(self, wait_s: float | None) -> None:
        """Wait up to ``wait_s`` (None: indefinitely) for the host, and serve what it does."""

    @abstractmethod
    def _drop_host(self) -> None:
        """The host went away: stop watching it, then ``_host_left()``."""

    # -- shared by the subclasses -------------------------------------------------------------
    def _host_came(self) -> None:
        self._connected_at = time.monotonic()
        self._record("*", "host connected")

    def _reset_for_host(self) -> None:
        self._connected_at = None
        self._ready = True
        self.printer.reset()
        if self.corruptor is not None:
            self.corruptor.reset()
        self._record("*", "board reset")

    def _host_left(self) -> None:
        self._connected_at = None
        self._ready = False
        self._unsent.clear()
        self._record("*", "host left")

    def _from_host(self, data: bytes) -> None:
        if self._connected_at is not None:
            self._reset_for_host()
        if self.corruptor is not None:
            data, flips = self.corruptor.feed(data)
            for index, bit in flips:
                self._record("*", f"rx corrupted: byte {index} of the next chunk, bit {bit}")
            if not data:
                return
        self._record(">", data)
        self._note_tx()
        self.printer.receive(data)

    def _note_tx(self) -> None:
        """A host that does not read fills Marlin's TX side: the main loop stalls in a write and
        only the RX interrupt runs (the ring fills, the rest is lost) until the host reads."""
        self.printer.tx_blocked = len(self._unsent) >= HOST_BUFFER_BYTES

    def _flush(self) -> None:
        """Write what the host takes now; the rest waits for POLLOUT."""
        if not self._unsent:
            return
        try:
            n = self._write(self._unsent)
        except BlockingIOError:
            return
        except ConnectionError:  # a TCP client gone
            self._drop_host()
            return
        self._record("<", bytes(self._unsent[:n]))
        del self._unsent[:n]

    def _record(self, direction: str, data: bytes | str) -> None:
        if self.transcript is not None:
            self.transcript.record(direction, self.printer.time_s, data)


def poll_ms(wait_s: float | None) -> float | None:
    """poll()'s timeout: milliseconds, never negative (which would mean forever)."""
    return None if wait_s is None else max(0.0, wait_s) * 1000
