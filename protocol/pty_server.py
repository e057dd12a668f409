"""The printer on a pseudo-terminal: a host opens its path (or a symlink to it) like a USB port."""

from __future__ import annotations

import errno
import os
import select

from protocol.corruption import RxCorruptor
from protocol.pacing import Pacer
from protocol.printer import VirtualPrinter
from protocol.pty import Pty, OpenWatch
from protocol.server import Server, poll_ms
from protocol.transcript import Transcript


class PtyServer(Server):
    """The printer on a pseudo-terminal: a host opens ``path`` (or ``link``) like a USB port.

    Who holds the port open is counted from inotify's open and close events on the slave
    device. They queue up, so a host closing and at once reopening is still seen; the
    master's POLLHUP (EIO on read) only shows a hang-up that lasts until the loop looks.
    """

    def __init__(self, printer: VirtualPrinter, pacer: Pacer | None = None, *, link: str | None = None,
                 transcript: Transcript | None = None, corruptor: RxCorruptor | None = None):
        super().__init__(printer, pacer, transcript, corruptor)
        self._pty = Pty(link)
        self.path, self.link = self._pty.path, self._pty.link
        self._master = self._pty.master
        self._watch: OpenWatch | None = self._pty.watch
        self._poller = select.poll()
        self._poller.register(self._pty.watch.fd, select.POLLIN)
        self._holders = 0  # open file descriptions of the slave: hosts (usually one)

    @property
    def address(self) -> str:
        return self.path

    def close(self) -> None:
        """Close the pty and the watch; remove the link if it still points at the pty."""
        self._pty.close()
        self.link, self._watch, self._master = None, None, -1

    def _write(self, data: bytes | bytearray) -> int:
        return os.write(self._master, data)

    def _wait(self, wait_s: float | None) -> None:
        if self._holders:
            self._poller.modify(self._master, select.POLLIN | (select.POLLOUT if self._unsent else 0))
        watch = self._watch
        if watch is None:
            raise OSError(errno.EBADF, "the pty server is closed")
        events = dict(self._poller.poll(poll_ms(wait_s)))
        if watch.fd in events:  # first: after a close and a reopen, the data is the new host's
            changes = watch.changes()
            for k, change in enumerate(changes):
                self._holders += change
                if change > 0 and self._holders == 1:
                    self._poller.register(self._master, select.POLLIN)
                    self._host_came()
                elif change < 0 and self._holders == 0:
                    if 1 not in changes[k + 1 :]:  # else a host already reopened it: the bytes are its
                        self._read()  # the last bytes it sent are still there
                    self._drop_host()
        revents = events.get(self._master, 0) if self._holders else 0
        if revents & select.POLLOUT:
            self._flush()
        if revents & (select.POLLIN | select.POLLHUP | select.POLLERR):
            self._read()

    def _read(self) -> None:
        for data in self._pty.chunks():
            self._from_host(data)

    def _drop_host(self) -> None:
        """The last holder closed the port (the master would report POLLHUP at every poll)."""
        self._poller.unregister(self._master)
        self._host_left()
