"""The printer on a TCP port (pyserial's ``socket://``, Pronterface's host:port), and who may drive it.

A TCP port can be reached by any local process, and beyond loopback by any host that can route to
it, none of which the user chose; the port takes a client's bytes as a USB cable would. So:

- it listens on loopback unless told otherwise, and another address needs a shared secret (every
  client's first line) or an explicit ``allow_remote``;
- one client has the printer at a time. A newcomer takes it over only when it sent the secret, or
  when the current client has been quiet for ``takeover_after_s`` (wall time) while the printer
  owed it nothing: no command executing or queued for it, or one stuck on output it does not read.
  So a stranger cannot reset a print a host is running, and a host that died without closing (a
  crashed machine, a dropped link: the socket stays half-open) blocks the printer for that long
  at most. A refused newcomer gets one ``Error:`` line, then the end of the stream (what it still
  sends is read and dropped for up to LINGER_S, so that it can read that line: a socket closed
  with input unread is reset, and a reset can discard the line);
- a client that waits to say the secret gets SECRET_TIMEOUT_S and SECRET_LINE_MAX bytes; at most
  MAX_PENDING connections wait or linger at once (more are closed at once), so they cannot
  exhaust the server.
"""

from __future__ import annotations

import hmac
import ipaddress
import select
import socket
import time
from dataclasses import dataclass, field

from protocol.corruption import RxCorruptor
from protocol.pacing import Pacer
from protocol.printer import VirtualPrinter
from protocol.server import READ_SIZE, Server, poll_ms
from protocol.transcript import Transcript

TAKEOVER_AFTER_S = 30.0  # OctoPrint's default communication timeout is 30 s too
SECRET_TIMEOUT_S = 10.0
SECRET_LINE_MAX = 256
LINGER_S = 2.0
MAX_PENDING = 8


def is_loopback(host: str) -> bool:
    """Every address ``host`` names is a loopback one (a name is resolved; one that does not resolve is not)."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except socket.gaierror:
        return False
    return all(ipaddress.ip_address(info[4][0]).is_loopback for info in infos)


@dataclass
class _Pending:
    """A connection without the printer: waiting to say the secret, or refused and lingering."""

    sock: socket.socket
    deadline_s: float
    refused: bool = False
    received: bytearray = field(default_factory=bytearray)


class TcpServer(Server):
    """The printer on a TCP port, one client at a time (see the module's docstring for who).

    A client that closes leaves the printer free; each admitted client resets the board.
    ``secret``: the line every client must send first (not passed to the printer, not logged).
    """

    def __init__(self, printer: VirtualPrinter, pacer: Pacer | None = None, host: str = "127.0.0.1", port: int = 0, *,
                 transcript: Transcript | None = None, corruptor: RxCorruptor | None = None,
                 secret: bytes | None = None, allow_remote: bool = False, takeover_after_s: float = TAKEOVER_AFTER_S):
        if secret is not None and (not secret or b"\n" in secret):
            raise ValueError("the secret must be one non-empty line")
        if secret is None and not allow_remote and not is_loopback(host):
            raise ValueError(f"listening on {host} lets any host that reaches it drive (and reset) the printer: "
                             "give a shared secret (--secret-file), or accept that with --allow-remote")
        super().__init__(printer, pacer, transcript, corruptor)
        self.secret = secret
        self.takeover_after_s = takeover_after_s
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = socket.create_server((host, port), family=family)
        self._listener.setblocking(False)
        self._client: socket.socket | None = None
        self._heard_s = 0.0  # monotonic time the client was last heard from, or last owed something
        self._pending: dict[int, _Pending] = {}
        self._poller = select.poll()
        self._poller.register(self._listener, select.POLLIN)

    @property
    def address(self) -> str:
        host, port = self._listener.getsockname()[:2]
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"

    def close(self) -> None:
        for pending in self._pending.values():
            pending.sock.close()
        self._pending.clear()
        if self._client is not None:
            self._client.close()
            self._client = None
        self._listener.close()

    def _write(self, data: bytes | bytearray) -> int:
        if self._client is None:
            raise ConnectionResetError("no client")
        return self._client.send(data)

    def _wait(self, wait_s: float | None) -> None:
        self._quiet_s()  # a command that ends while we wait counts as heard up to here
        if self._pending:
            soonest_s = min(p.deadline_s for p in self._pending.values()) - time.monotonic()
            wait_s = soonest_s if wait_s is None else min(wait_s, soonest_s)
        if self._client is not None:
            self._poller.modify(self._client, select.POLLIN | (select.POLLOUT if self._unsent else 0))
        for fd, revents in self._poller.poll(poll_ms(wait_s)):
            self._serve(fd, revents)
        self._expire_pending()

    def _serve(self, fd: int, revents: int) -> None:
        """One ready descriptor: the listener accepts, a pending host is heard, the client written and read."""
        if fd == self._listener.fileno():
            self._accept()
        elif fd in self._pending:
            self._hear_pending(self._pending[fd])
        elif self._client is not None and fd == self._client.fileno():  # not a client replaced meanwhile
            if revents & select.POLLOUT:
                self._flush()
            if revents & (select.POLLIN | select.POLLHUP | select.POLLERR):
                self._read()

    def _expire_pending(self) -> None:
        """Hosts past their deadline: a refused one is closed, one that sent no secret is refused."""
        for pending in [p for p in self._pending.values() if p.deadline_s <= time.monotonic()]:
            if pending.refused:
                self._forget(pending).close()
            else:
                self._refuse(pending, f"no secret within {SECRET_TIMEOUT_S:g} s")

    def _accept(self) -> None:
        try:
            client, _ = self._listener.accept()
        except (BlockingIOError, ConnectionAbortedError):  # the client gave up before we took it
            return
        except OSError as exc:  # out of file descriptors: serve the client there is
            self._record("*", f"connection not accepted: {exc.strerror or exc}")
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # replies are short lines
        if len(self._pending) >= MAX_PENDING:
            client.close()
            self._record("*", "host refused: too many connections waiting")
            return
        pending = _Pending(client, time.monotonic() + SECRET_TIMEOUT_S)
        self._pending[client.fileno()] = pending
        self._poller.register(client, select.POLLIN)
        if self.secret is not None:
            return  # its first line decides
        if self._client is not None:
            self._read()  # what it sent before this newcomer counts: it was not quiet
        if self._client is None or self._quiet_s() >= self.takeover_after_s:
            self._admit(pending, b"")
        else:
            self._refuse(pending, f"the printer is in use by another host; it can be taken over once that host "
                                  f"has left it waiting {self.takeover_after_s:g} s")

    def _quiet_s(self) -> float:
        """Wall seconds the client has left the printer waiting for it: since its last byte, or since
        the printer last had one of its commands to run (not one stuck on output the client leaves unread)."""
        if self.printer.busy and not self.printer.tx_blocked:
            self._heard_s = time.monotonic()
        return time.monotonic() - self._heard_s

    def _hear_pending(self, pending: _Pending) -> None:
        """A refused connection's bytes are dropped; a waiting one's first line is the secret, which
        admits it (taking the printer over), or anything else, which refuses it."""
        try:
            data = pending.sock.recv(READ_SIZE)
        except BlockingIOError:
            return
        except ConnectionError:
            data = b""
        if not data:
            self._forget(pending).close()
            return
        if pending.refused:
            return
        pending.received += data
        line, eol, rest = bytes(pending.received).partition(b"\n")
        if not eol:
            if len(pending.received) > SECRET_LINE_MAX:
                self._refuse(pending, "wrong secret")
            return
        assert self.secret is not None
        if hmac.compare_digest(line.rstrip(b"\r"), self.secret):
            self._admit(pending, rest)
        else:
            self._refuse(pending, "wrong secret")

    def _forget(self, pending: _Pending) -> socket.socket:
        self._poller.unregister(pending.sock)
        del self._pending[pending.sock.fileno()]
        return pending.sock

    def _admit(self, pending: _Pending, first_bytes: bytes) -> None:
        """The pending connection has the printer now (the client before it is closed); its board resets."""
        client = self._forget(pending)
        if self._client is not None:
            self._record("*", "host replaced")
            self._drop_host()
        self._poller.register(client, select.POLLIN)
        self._client = client
        self._heard_s = time.monotonic()
        self._host_came()
        if first_bytes:
            self._from_host(first_bytes)

    def _refuse(self, pending: _Pending, why: str) -> None:
        """One line for the refused connection, the end of its stream, and LINGER_S for it to read them."""
        try:
            pending.sock.send(f"Error:{why}\n".encode())
            pending.sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        pending.refused = True
        pending.deadline_s = time.monotonic() + LINGER_S
        self._record("*", f"host refused: {why}")

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
            self._heard_s = time.monotonic()
            self._from_host(data)
        else:
            self._drop_host()

    def _drop_host(self) -> None:
        if self._client is not None:
            self._poller.unregister(self._client)
            self._client.close()
            self._client = None
            self._host_left()
