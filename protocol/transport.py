"""Transports: a VirtualPrinter on a pseudo-terminal or a TCP port, paced to the wall clock.

One thread and one poll() loop: bytes from the host go to the printer, the printer's virtual
clock advances as the speed says, its output goes back. Speed N runs the clock at N x wall
time; ``max`` runs it free while a command executes (M109, M190, M303, G4) and stops it while
the printer waits for the host (DESIGN.md, the clock). A host opening the port (pty) or
connecting (TCP) resets the board, as a USB printer's DTR auto-reset does, so every connection
starts with Marlin's ``start`` banner; output nobody is connected to read is dropped. There is
no thread: a command that runs at ``max`` is served a virtual second at a time, so the host's
input (M108) and the printer's output flow while it runs.

Transcript (``--log FILE``): a ``#`` header line, then one line per chunk on the wire::

    <dir> <virtual_s> <wall_s> <data>

``dir`` is ``>`` host to printer, ``<`` printer to host, ``*`` an event ("host connected",
"board reset", "host left"). ``virtual_s``
is the printer's clock (scenario seconds) when the chunk passed, ``wall_s`` the seconds since
the transcript was opened. ``data`` is a Python literal: the bytes' repr, or the event's text
as a str repr; ``line.split(" ", 3)`` and ``ast.literal_eval`` read a line back.

Injected corruption (``--corrupt-rx P``, ``RxCorruptor``): a noisy wire on the printer's receive
side, so a host's resend handling gets exercised. Each line the host sends has, with probability
P, one random bit of one random byte flipped before the printer reads it: any bit of any byte,
the line's end included, as on a real wire, and Marlin's line-number and checksum checks catch
what they catch. The transcript shows what the printer received, each flip announced by a ``*``
event naming the byte (in the ``>`` chunk that follows) and the bit.
"""

from __future__ import annotations

import ctypes
import errno
import math
import os
import random
import select
import socket
import struct
import time
import tty
from abc import ABC, abstractmethod
from collections import OrderedDict
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Literal

from protocol.printer import VirtualPrinter
from protocol.settings import Eeprom
from twin.build import build_twin
from twin.linear import TICK_S
from twin.scenario import parse_scenario, scenario_for, with_overrides

MAX: Literal["max"] = "max"
Speed = float | Literal["max"]
# Idle clock speed for twin-serial and twin://: real time. OctoPrint's and Pronterface's graphs,
# timeouts and heat-up expectations are in wall seconds, so an idle printer behaves as the real
# one does; the long waits (M109, M190, M303, G4, M400) are where speed matters, and they run free.
DEFAULT_IDLE_SPEED = 1.0

PACE_S = 0.01  # speed N: wall seconds between clock updates, the timing resolution a host sees
CATCH_UP_S = 0.05  # speed N: one update runs at most this much wall time's worth of virtual time
FREE_STEP_S = 1.0  # speed max: virtual seconds per update (M109 reports once a second)
BOOT_DELAY_S = 0.2  # host connects -> board reset, unless its first bytes come sooner (a bootloader: ~1 s)
READ_SIZE = 4096
HOST_BUFFER_BYTES = 4096  # output a host may leave unread before Marlin's writes block (Linux N_TTY_BUF_SIZE)

# A serial printer has no setpoints of its own: the host sets them.
SERIAL_SCENARIO = parse_scenario('name = "serial"\nduration_s = 86400\n', "serial")


def default_idle_speed(speed: Speed) -> float:
    """The idle clock when none is given: DEFAULT_IDLE_SPEED under ``--speed max``, else the same
    N as ``--speed N`` (one speed for the whole session, as ``--speed N`` always meant)."""
    return DEFAULT_IDLE_SPEED if speed == MAX else speed


def parse_idle_speed(text: str) -> float:
    """A factor of real time >= 0; 0 is the host-driven clock (stopped while the host is idle)."""
    try:
        speed = float(text)
    except ValueError:
        speed = math.nan
    if not (math.isfinite(speed) and speed >= 0):
        raise ValueError(f"idle speed must be a number >= 0 (1 = real time, 0 = host-driven clock), not {text!r}")
    return speed


def parse_speed(text: str) -> Speed:
    """``max``, or a positive factor of real time (``1`` is real time)."""
    if text == MAX:
        return MAX
    try:
        speed = float(text)
    except ValueError:
        speed = math.nan
    if not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be 'max' or a positive number (1 = real time), not {text!r}")
    return speed


def build_printer(*, firmware: str = "pid", plant: str | None = None, bed_plant: str | None = None,
                  with_bed: bool = True, scenario: str | None = None, settings: str | None = None,
                  ok_after_resend: bool = True) -> VirtualPrinter:
    """The printer twin-serial and twin:// serve; ValueError names a bad option.

    ``scenario`` (a preset name or TOML file) brings faults, ambient and plant overrides;
    ``settings`` is the file M500 writes (the EEPROM), by default kept in memory only.
    """
    chosen = scenario_for(scenario) if scenario else SERIAL_SCENARIO
    # firmware and plant names are checked where they are used (build_controllers, make_plant)
    presets = {heater: {"preset": name} for heater, name in (("hotend", plant), ("bed", bed_plant)) if name}
    if presets:
        chosen = with_overrides(chosen, plant=presets)
    eeprom = Eeprom.open(settings) if settings else None
    return VirtualPrinter(lambda: build_twin(chosen, firmware, with_bed=with_bed, engine="fast"),
                          eeprom=eeprom, ok_after_resend=ok_after_resend)


class Pacer:
    """Turns wall time into the printer's virtual time: the clock that keeps running.

    While a command executes (M109, M190, M303, G4, M400, a G1 waiting for the planner) the
    clock runs at ``speed``: ``max`` runs it free, a virtual second per call, so such commands
    end in seconds; N runs it at N x the wall time. Otherwise it runs at ``idle_speed`` x the
    wall time, so a target set with M104 heats and M155 reports come while the host only
    listens. ``idle_speed`` 0 is the host-driven clock: it stops while the printer waits for the
    host (at ``max``, moves left in the planner still run free), which makes a session a pure
    function of the bytes sent: the deterministic mode for tests. A paced step runs at most
    CATCH_UP_S of wall time's worth, so a twin slower than asked still serves its host between.
    """

    def __init__(self, printer: VirtualPrinter, speed: Speed = MAX, idle_speed: float | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.printer = printer
        self.speed = speed
        self.idle_speed = default_idle_speed(speed) if idle_speed is None else idle_speed
        self.clock = clock
        self._accounted_s = clock()  # wall time already turned into virtual time
        if not self.host_driven:
            printer.wall_clock = clock  # reports and keepalives: at most once per wall interval too

    @property
    def host_driven(self) -> bool:
        """The clock stops while the printer waits for the host (``idle_speed`` 0)."""
        return self.idle_speed == 0

    @property
    def runs_free(self) -> bool:
        """The next advance() runs the clock free (one FREE_STEP_S of virtual time)."""
        return self.speed == MAX and (self.printer.executing or self.host_driven)

    def advance(self) -> float | None:
        """Run the clock as far as the speeds allow now.

        Returns how long the caller may wait for the host before the next call: 0 when there
        is more to run at once, None when nothing happens until the host sends something.
        """
        printer = self.printer
        if self.runs_free:
            return self._run_free()
        speed = self.speed if printer.executing else self.idle_speed
        now_s = self.clock()
        if speed == 0:  # host-driven and idle: the clock waits, and owes the wall nothing
            self._accounted_s = now_s
            return None
        due_s = (now_s - self._accounted_s) * speed
        step_s = min(due_s, CATCH_UP_S * speed)
        if step_s > 0:
            printer.run_for(step_s)
            self._accounted_s += step_s / speed
        return 0.0 if due_s > step_s else PACE_S

    def _run_free(self) -> float | None:
        printer = self.printer
        start_s = printer.time_s
        if self.host_driven:
            printer.run_until_idle(FREE_STEP_S)
        else:
            printer.run_while_busy(FREE_STEP_S)
        self._accounted_s = self.clock()  # free time owes the wall nothing
        # It returns early once the printer waits for the host; a halted board runs nothing.
        still_busy = printer.time_s - start_s > FREE_STEP_S - TICK_S / 2 and not printer.halted
        if still_busy:
            return 0.0
        return None if self.host_driven else PACE_S


class Transcript:
    """The ``--log`` file: both directions of the wire with virtual and wall times (see above)."""

    def __init__(self, path: str | Path, clock: Callable[[], float] = time.monotonic):
        self._file = open(path, "w", encoding="utf-8", buffering=1)  # a line at a time: tail -f works
        self._clock = clock
        self._wall0_s = clock()
        started = datetime.now().astimezone().isoformat(timespec="seconds")
        self._file.write(f"# heater-twin transcript started {started}: dir virtual_s wall_s data "
                         "(> host to printer, < printer to host, * event)\n")

    def record(self, direction: str, virtual_s: float, data: bytes | str) -> None:
        self._file.write(f"{direction} {virtual_s:.6f} {self._clock() - self._wall0_s:.6f} {data!r}\n")

    def close(self) -> None:
        self._file.close()


class RxCorruptor:
    """Flips one random bit of one random byte in a fraction of the host's lines (``--corrupt-rx``).

    Lines are cut at every CR or LF (the end of line belongs to its line and may be hit too);
    bytes after the last one wait for the rest of their line, which changes nothing the printer
    does, as Marlin acts on a line only at its end. Whether and where a line is hit is drawn by
    ``random.Random`` seeded with the seed, the line's bytes and how many times the same bytes
    came before (since ``reset()``, a host's arrival): a resent line gets a fresh draw, and a
    host that sends the same lines gets the same flips every run, however its writes are cut up,
    and whatever it sends in between (an extra line a host's race sends does not move the flips
    onto other lines). Python keeps string seeding and ``random()``'s sequence across versions.
    Repeats are counted for the last REPEATS_KEPT distinct lines: a resend asks for a recent one.

    No flip makes the printer raise or hang, but some stop a host as they would on a real
    printer. A flipped end of line leaves its line open until the host sends more, and a line
    number flipped to the last one is dropped silently as a duplicate: a host that sends the
    next line only after an ``ok`` and has no timeout (Printrun's printcore) waits forever. An
    unnumbered ``M110`` or ``M113`` can become ``M112``, which kills the board; a numbered line
    cannot (Marlin looks for emergency commands only at the start of a line).
    """

    REPEATS_KEPT = 1024

    def __init__(self, probability: float, seed: int = 0):
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"the rx corruption probability (--corrupt-rx) must be within 0..1, "
                             f"not {probability!r}")
        self.probability = probability
        self.seed = seed
        self.reset()

    def reset(self) -> None:
        """Forget the lines seen and a partial line (a new host, a board reset)."""
        self._seen: OrderedDict[bytes, int] = OrderedDict()
        self._partial = bytearray()

    def feed(self, data: bytes) -> tuple[bytes, list[tuple[int, int]]]:
        """The complete lines in ``data`` (after what waited), some corrupted, and the flips
        made as (index of the byte in the returned bytes, bit 0..7)."""
        self._partial += data
        end = max(self._partial.rfind(b"\n"), self._partial.rfind(b"\r")) + 1
        lines = self._partial[:end]
        del self._partial[:end]
        flips = []
        start = 0
        for i in range(end):
            if lines[i] in b"\r\n":
                flip = self._draw(bytes(lines[start:i + 1]))
                if flip is not None:
                    index, bit = start + flip[0], flip[1]
                    lines[index] ^= 1 << bit
                    flips.append((index, bit))
                start = i + 1
        return bytes(lines), flips

    def _draw(self, line: bytes) -> tuple[int, int] | None:
        """The (byte index, bit) to flip in this occurrence of ``line``, or None."""
        repeat = self._seen.pop(line, -1) + 1
        self._seen[line] = repeat
        if len(self._seen) > self.REPEATS_KEPT:
            self._seen.popitem(last=False)
        rng = random.Random(f"{self.seed}:{repeat}:{line.hex()}")
        if rng.random() >= self.probability:
            return None
        return int(rng.random() * len(line)), int(rng.random() * 8)


class _Server(ABC):
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

    def serve_forever(self) -> None:
        """Serve until interrupted (KeyboardInterrupt, or SystemExit from a SIGTERM handler)."""
        while True:
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
        # A host that does not read fills Marlin's TX side: the main loop stalls in a write and
        # only the RX interrupt runs (the ring fills, the rest is lost) until the host reads.
        self.printer.receive(data, loop_running=len(self._unsent) < HOST_BUFFER_BYTES)

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


class PtyServer(_Server):
    """The printer on a pseudo-terminal: a host opens ``path`` (or ``link``) like a USB port.

    Who holds the port open is counted from inotify's open and close events on the slave
    device. They queue up, so a host closing and at once reopening is still seen; the
    master's POLLHUP (EIO on read) only shows a hang-up that lasts until the loop looks.
    """

    def __init__(self, printer: VirtualPrinter, pacer: Pacer | None = None, *, link: str | None = None,
                 transcript: Transcript | None = None, corruptor: RxCorruptor | None = None):
        super().__init__(printer, pacer, transcript, corruptor)
        self._master, slave = os.openpty()
        try:
            tty.setraw(slave)  # no echo, no CR/LF translation, 8 bits; the setting outlives the fd
            self.path = os.ttyname(slave)
        finally:
            os.close(slave)  # before the watch starts: from now on only hosts hold it
        os.set_blocking(self._master, False)
        self._watch: _OpenWatch | None = None
        self.link = None
        try:
            self._watch = _OpenWatch(self.path)
            if link:
                _make_link(self.path, link)
                self.link = link
        except OSError:
            self.close()
            raise
        self._poller = select.poll()
        self._poller.register(self._watch.fd, select.POLLIN)
        self._holders = 0  # open file descriptions of the slave: hosts (usually one)

    @property
    def address(self) -> str:
        return self.path

    def close(self) -> None:
        """Close the pty and the watch; remove the link if it still points at the pty."""
        if self.link and os.path.islink(self.link) and os.readlink(self.link) == self.path:
            os.remove(self.link)
        self.link = None
        if self._watch is not None:
            self._watch.close()
            self._watch = None
        if self._master >= 0:
            os.close(self._master)
            self._master = -1

    def _write(self, data: bytes | bytearray) -> int:
        return os.write(self._master, data)

    def _wait(self, wait_s: float | None) -> None:
        if self._holders:
            self._poller.modify(self._master, select.POLLIN | (select.POLLOUT if self._unsent else 0))
        events = dict(self._poller.poll(_poll_ms(wait_s)))
        if self._watch.fd in events:  # first: after a close and a reopen, the data is the new host's
            changes = self._watch.changes()
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
        """Everything the host sent, until EAGAIN (or EIO once nobody holds the port)."""
        while True:
            try:
                data = os.read(self._master, READ_SIZE)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return
                raise
            self._from_host(data)

    def _drop_host(self) -> None:
        """The last holder closed the port (the master would report POLLHUP at every poll)."""
        self._poller.unregister(self._master)
        self._host_left()


class TcpServer(_Server):
    """The printer on a TCP port (pyserial's ``socket://``, Pronterface's host:port).

    One client at a time; others wait in the listen backlog. Each connection resets the board.
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
        return self._client.send(data)

    def _wait(self, wait_s: float | None) -> None:
        if self._client is not None:
            self._poller.modify(self._client, select.POLLIN | (select.POLLOUT if self._unsent else 0))
        for fd, revents in self._poller.poll(_poll_ms(wait_s)):
            if fd == self._listener.fileno():
                self._accept()
            elif self._client is not None:
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
        self._poller.unregister(self._listener)
        self._poller.register(client, select.POLLIN)
        self._client = client
        self._host_came()

    def _read(self) -> None:
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
            self._poller.register(self._listener, select.POLLIN)
            self._host_left()


def _poll_ms(wait_s: float | None) -> float | None:
    """poll()'s timeout: milliseconds, never negative (which would mean forever)."""
    return None if wait_s is None else max(0.0, wait_s) * 1000


class _OpenWatch:
    """Open and close events of one file, from Linux's inotify (via libc: no stdlib binding)."""

    IN_OPEN, IN_CLOSE_WRITE, IN_CLOSE_NOWRITE = 0x20, 0x08, 0x10  # <sys/inotify.h>
    EVENT = struct.Struct("iIII")  # struct inotify_event: wd, mask, cookie, len (+ name, empty here)

    def __init__(self, path: str):
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
