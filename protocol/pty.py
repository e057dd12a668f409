"""A pseudo-terminal a host opens like a USB port: the master, the raw slave's path, the watch of
who holds it open, a symlink. Light on purpose (the standard library only): a server makes its pty
and prints the path before it imports the twin."""

from __future__ import annotations

import ctypes
import errno
import os
import struct
import tty
from collections.abc import Iterator

READ_SIZE = 4096  # bytes per read of the master or the watch


class Pty:
    """A pseudo-terminal a host opens like a USB port: the master (non-blocking), the slave's path
    (raw: no echo, no CR/LF translation, 8 bits), the inotify watch of who holds the slave open, and
    an optional symlink to it. ``close`` releases them all."""

    def __init__(self, link: str | None = None):
        self.master, slave = os.openpty()
        try:
            tty.setraw(slave)  # the setting outlives the fd
            self.path = os.ttyname(slave)
        finally:
            os.close(slave)  # before the watch starts: from now on only hosts hold it
        os.set_blocking(self.master, False)
        self.link: str | None = None
        try:
            self.watch = OpenWatch(self.path)
        except OSError:
            os.close(self.master)
            raise
        try:
            if link:
                _make_link(self.path, link)
                self.link = link
        except OSError:
            self.close()
            raise

    def __repr__(self) -> str:
        return f"Pty({self.path}{' -> ' + self.link if self.link else ''})"

    def chunks(self) -> Iterator[bytes]:
        """Everything the host sent, until EAGAIN (or EIO once nobody holds the port)."""
        while True:
            try:
                data = os.read(self.master, READ_SIZE)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return
                raise
            if not data:
                return
            yield data

    def close(self) -> None:
        """Close the master and the watch; remove the link if it still points at the pty."""
        if self.link and os.path.islink(self.link) and os.readlink(self.link) == self.path:
            os.remove(self.link)
        self.link = None
        if self.master >= 0:
            self.watch.close()
            os.close(self.master)
            self.master = -1


class OpenWatch:
    """Open and close events of one file, from Linux's inotify (via libc: no stdlib binding)."""

    IN_OPEN, IN_CLOSE_WRITE, IN_CLOSE_NOWRITE = 0x20, 0x08, 0x10  # <sys/inotify.h>
    EVENT = struct.Struct("iIII")  # struct inotify_event: wd, mask, cookie, len (+ name, empty here)

    def __init__(self, path: str):
        self.path = path
        libc = ctypes.CDLL(None, use_errno=True)
        if not hasattr(libc, "inotify_init1"):
            raise OSError(errno.ENOSYS, "the pty transport needs Linux (inotify); use --tcp")
        self.fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if self.fd < 0:
            raise OSError(ctypes.get_errno(), "inotify_init1: " + os.strerror(ctypes.get_errno()))
        mask = self.IN_OPEN | self.IN_CLOSE_WRITE | self.IN_CLOSE_NOWRITE
        if libc.inotify_add_watch(self.fd, os.fsencode(path), mask) < 0:
            err = ctypes.get_errno()
            os.close(self.fd)
            raise OSError(err, "inotify_add_watch: " + os.strerror(err), path)

    def __repr__(self) -> str:
        return f"OpenWatch({self.path}, fd {self.fd})"

    def changes(self) -> list[int]:
        """+1 per open and -1 per close since the last call, in the order they happened."""
        changes: list[int] = []
        while True:
            try:
                data = os.read(self.fd, READ_SIZE)
            except BlockingIOError:
                return changes
            offset = 0
            while offset < len(data):
                _, mask, _, name_len = self.EVENT.unpack_from(data, offset)
                offset += self.EVENT.size + name_len
                if mask & self.IN_OPEN:
                    changes.append(1)
                elif mask & (self.IN_CLOSE_WRITE | self.IN_CLOSE_NOWRITE):
                    changes.append(-1)

    def close(self) -> None:
        os.close(self.fd)


def _make_link(target: str, link: str) -> None:
    """Point ``link`` at ``target``, replacing an older symlink but never any other file."""
    if os.path.lexists(link) and not os.path.islink(link):
        raise FileExistsError(errno.EEXIST, "exists and is not a symlink; not replacing it", link)
    temporary = f"{link}.{os.getpid()}.tmp"
    try:
        os.symlink(target, temporary)
        os.replace(temporary, link)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot make the link: {exc.strerror}", link) from None
