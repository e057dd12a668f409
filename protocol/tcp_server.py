"""The printer on a TCP port (pyserial's ``socket://``, Pronterface's host:port)."""

from __future__ import annotations

import select
import socket

from protocol.corruption import RxCorruptor
from protocol.pacing import Pacer
from protocol.printer import VirtualPrinter
from protocol.server import READ_SIZE, Server, poll_ms
from protocol.transcript import Transcript


class TcpServer(Server):
    """The printer on a TCP port (pyserial's ``socket://``, Pronterface's host:port).

    One client at a time, and the newest one has the printer: a connection that arrives while
    another is open takes it over, as plugging a USB cable into a second computer does; the old
    client's socket is closed ("host replaced" in the transcript). A client that went silent
    without closing (a crashed host, a dropped Wi-Fi link) so never blocks the next one. Each
    connection resets the board.
    """

    def __init__(self, printer: VirtualPrinter, pacer: Pacer | None = None, host: str = "127.0.0.1", port: int = 0, *,
                 transcript: Transcript | None = None, corruptor: RxCorruptor | None = None):
        super().__init__(printer, pacer, transcript, corruptor)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = socket.create_server((host, port), family=family)
        self._listener.setblocking(False)
        self._client: socket.socket | None = None
        self._poller = select.poll()
        self._poller.register(self._listener, select.POLLIN)

    @property
    def address(self) -> str:
        host, port = self._listener.getsockname()[:2]
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None
        self._listener.close()

    def _write(self, data: bytes | bytearray) -> int:
        if self._client is None:
            raise ConnectionResetError("no client")
        return self._client.send(data)

    def _wait(self, wait_s: float | None) -> None:
        if self._client is not None:
            self._poller.modify(self._client, select.POLLIN | (select.POLLOUT if self._unsent else 0))
        for fd, revents in self._poller.poll(poll_ms(wait_s)):
            if fd == self._listener.fileno():
                self._accept()
            elif self._client is not None and fd == self._client.fileno():  # not a client replaced meanwhile
                if revents & select.POLLOUT:
                    self._flush()
                if revents & (select.POLLIN | select.POLLHUP | select.POLLERR):
                    self._read()

    def _accept(self) -> None:
        try:
            client, _ = self._listener.accept()
        except BlockingIOError:  # the client gave up before we took it
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # replies are short lines
        if self._client is not None:  # the newcomer takes the printer over
            self._record("*", "host replaced")
            self._drop_host()
        self._poller.register(client, select.POLLIN)
        self._client = client
        self._host_came()

    def _read(self) -> None:
        if self._client is None:
            return
        try:
            data = self._client.recv(READ_SIZE)
        except BlockingIOError:
            return
        except ConnectionError:
            data = b""
        if data:
            self._from_host(data)
        else:
            self._drop_host()

    def _drop_host(self) -> None:
        if self._client is not None:
            self._poller.unregister(self._client)
            self._client.close()
            self._client = None
            self._host_left()
