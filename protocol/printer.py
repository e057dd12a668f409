"""A Marlin 2.1 printer on a serial line: bytes in, Marlin's replies out, a twin underneath.

``VirtualPrinter`` is what a transport (pty, TCP, the pyserial URL handler) talks to. It keeps
Marlin's RX line layer and command queue (BUFSIZE 4), runs one command at a time, and owns the
twin's clock: a command that takes time (M109, M190, M303, G4, M400, a G1 into a full planner)
is a generator that yields the tick it wants to be resumed at, and the clock runs to it while
Marlin's idle() duties happen on the way (busy keepalive every 2 s, M155 auto-reports).

The transport decides how fast virtual time passes: ``run_for(seconds)`` for a speed of N x real
time, ``run_while_busy()`` for ``--speed max`` (run free while a command executes). A transport
that paces to the wall clock sets ``wall_clock``: M155 reports and busy keepalives then come at
most once per interval of virtual time *and* of wall time, so a clock running 500 x real time
does not send a host 500 lines a second (without it, both follow virtual time only, which keeps
host-driven runs deterministic).

The receive side is an ATmega328's behind a 115200-baud wire (``protocol/link.py``): bytes arrive
at the link's byte rate in virtual time, so an instant command (M110) runs before the line a host
pipelined behind it has arrived, as on the board. They land in a 128-byte RX ring (Marlin's
RX_BUFFER_SIZE) that the main loop empties only while the command queue has room; bytes that
arrive to a full ring are lost, as MarlinSerial's store_rxd_char() drops them. A host that writes
more than its serial buffer (WIRE_BUFFER_BYTES) ahead of the wire waits: ``receive()`` runs the
clock until the wire has taken the excess, as a real writer's write() blocks. A command that raises is a bug of the twin, not
of the host: it is logged, answered with ``Error:`` and ``ok``, and the printer keeps serving.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Generator

from firmware_port.marlin.constants import ms_to_ticks, ticks_to_ms
from protocol.commands import DEFAULT_KEEPALIVE_S, HANDLERS, NO_OK, banner
from protocol.gcode import Command, parse, unknown_command_text
from protocol.lines import Line, LineReader
from protocol.link import SerialLink, first_eol
from protocol.planner import Planner
from protocol.settings import Eeprom
from twin.engine import Twin
from twin.linear import TICK_S

BUFSIZE = 4  # Marlin's command ring buffer
RX_BUFFER_SIZE = 128  # Marlin Configuration_adv.h (AVR); the ring keeps one slot empty, so 127 bytes
RX_CAPACITY = RX_BUFFER_SIZE - 1
WIRE_BUFFER_BYTES = 4096  # what a host's serial driver holds before its write() blocks (Linux N_TTY_BUF_SIZE)
TICKS_PER_S = 1.0 / TICK_S
BOOT_TICKS = round(1.0 * TICKS_PER_S)  # from reset to the host's first command: readings are in

Task = Generator[int, None, None]  # yields the absolute tick to be resumed at
LOG = logging.getLogger(__name__)


class VirtualPrinter:
    """Marlin's serial front end and command loop over a twin."""

    def __init__(self, make_twin: Callable[[], Twin], *, eeprom: Eeprom | None = None, ok_after_resend: bool = True):
        self.twin = make_twin()
        self.twin.recording = False  # a serial session can run for days: no trace rows
        self.eeprom = eeprom if eeprom is not None else Eeprom()
        self.reader = LineReader(ok_after_resend=ok_after_resend)
        self._out = bytearray()
        self.twin.console.listeners.append(self._to_wire)
        self._boots = 0
        self.wall_clock: Callable[[], float] | None = None  # set by a transport paced to the wall
        self.rx_dropped = 0  # bytes lost to a full RX ring since the printer was made
        self.link = SerialLink()
        # Set by a transport whose host leaves Marlin's output unread: Marlin's main loop is then
        # stuck writing to a full TX buffer, reads no line, and only the receive interrupt runs.
        self.tx_blocked = False
        self.internal_errors = 0  # commands that raised (a bug of the twin), answered with Error:
        self.reset()

    def __repr__(self) -> str:
        return f"VirtualPrinter(t={self.time_s:.3f} s, {len(self.queue)} queued{', halted' if self.halted else ''}, {self.twin!r})"

    # -- what a transport uses ------------------------------------------------------------
    def reset(self) -> None:
        """Reset the board (DTR toggle, new connection): the banner, settings from the EEPROM."""
        self.twin.reset_board()
        self.reader.reset()
        self.link.clear()
        self._rx = bytearray()
        self.queue: deque[Line] = deque()
        self.current: Task | None = None
        self.wake_tick = 0
        self.wait_for_heatup = False
        self.idle_calls = True  # False while a command's loop skips idle() (M303)
        self.planner = Planner()
        self.twin.flow_mm_s = 0.0
        self.keepalive_s = DEFAULT_KEEPALIVE_S
        self.keepalive_tick = 0
        self.autoreport_s = 0
        self.autoreport_tick = 0
        self.autoreport_wall_s = 0.0
        self.keepalive_wall_s = 0.0
        self.write(banner(self, power_up=self._boots == 0))
        self._boots += 1
        self.twin.run_ticks(BOOT_TICKS)  # setup() finishes; the first readings come in
        self.twin.origin_tick = self.twin.tick  # time_s counts from here

    def receive(self, data: bytes) -> None:
        """The host writes ``data``: onto the wire, whose first line on an idle link arrives at
        once and the rest at the byte rate as the clock runs (see the module's docstring)."""
        if self.halted:
            return
        self.link.send(data, self.twin.tick)
        self._take_arrivals()
        if self.link.in_flight > WIRE_BUFFER_BYTES:  # the host's write blocks until the wire drains
            self._run(max(self.twin.tick, self.link.drained_tick(WIRE_BUFFER_BYTES)))

    @property
    def receiving(self) -> bool:
        """Bytes are on the wire, still arriving (the clock must run for them)."""
        return self.link.in_flight > 0 and not self.halted

    def _take_arrivals(self) -> None:
        """The bytes that have arrived by now, a line at a time into the ring; between two lines
        the main loop (unless stuck on a full TX buffer) reads and runs what it can."""
        data = self.link.take(self.twin.tick)
        start = 0
        while start < len(data):
            if self.halted or (len(self._rx) >= RX_CAPACITY and not self._reads_lines):
                self.rx_dropped += len(data) - start  # a full ring nobody reads: all of it is lost
                return
            end = first_eol(data, start) + 1 or len(data)
            self._to_ring(data[start:end])
            start = end

    def _to_ring(self, piece: bytes) -> None:
        """The ring takes what fits; the main loop empties it line by line while the queue has
        room; what arrives to a full ring is dropped (``rx_dropped``)."""
        view = memoryview(piece)
        while view:
            taken = min(len(view), RX_CAPACITY - len(self._rx))
            self._rx += view[:taken]
            view = view[taken:]
            if self.tx_blocked:
                break
            before = len(self._rx)
            self._read_lines()
            self._dispatch()
            if taken == 0 and len(self._rx) >= before:  # the ring is full and nothing reads it
                break
        self.rx_dropped += len(view)

    def take_output(self) -> bytes:
        """Everything printed since the last call."""
        data = bytes(self._out)
        self._out.clear()
        return data

    @property
    def output_waiting(self) -> int:
        """Bytes printed and not taken yet."""
        return len(self._out)

    def _to_wire(self, text: str) -> None:
        self._out.extend(text.encode("latin-1"))
        self.twin.console.text = ""  # the wire is the record: a session may run for weeks

    @property
    def halted(self) -> bool:
        return self.twin.board.halted

    @property
    def busy(self) -> bool:
        """A command is executing or waiting in the queue."""
        return not self.halted and (self.current is not None or bool(self.queue))

    @property
    def time_s(self) -> float:
        """Virtual seconds since the board's last reset (and boot)."""
        return self.twin.time_s

    def run_for(self, seconds: float) -> None:
        """Let ``seconds`` of virtual time pass, doing what Marlin does meanwhile."""
        self._run(self.twin.tick + max(0, round(seconds * TICKS_PER_S)))

    def run_until_idle(self, max_seconds: float = 7200.0) -> None:
        """Host-driven ``max``: run free while a command executes or moves remain, stop when
        the printer waits for the host."""
        self._run(self.twin.tick + round(max_seconds * TICKS_PER_S), stop_when=_idle_and_still)

    def run_while_busy(self, max_seconds: float) -> None:
        """Run free while a command executes or bytes are arriving (up to ``max_seconds``); moves
        left over keep running later, at the transport's idle speed."""
        self._run(self.twin.tick + round(max_seconds * TICKS_PER_S), stop_when=_no_command)

    @property
    def executing(self) -> bool:
        """A command is executing (it blocks the queue: M109, M190, M303, G4, M400, a G1 waiting
        for the planner): what a transport runs at its busy speed."""
        return self.current is not None and not self.halted

    # -- what commands use ------------------------------------------------------------------
    def write(self, text: str) -> None:
        """Serial TX from the command layer (the firmware's console shares the same wire)."""
        self.twin.console.write(text)

    @property
    def now_tick(self) -> int:
        return self.twin.tick

    def after_ms(self, ms: int) -> int:
        """The tick at which the board's millis() will have advanced by ``ms``."""
        board = self.twin.board
        return self.twin.tick + ms_to_ticks(ticks_to_ms(board.ticks) + ms) - board.ticks

    def next_reading_tick(self) -> int:
        """The tick of the board's next main-loop action (a fresh reading, an M303 deadline)."""
        return self.twin.tick + self.twin.board.ticks_to_task()

    # -- the loop -------------------------------------------------------------------------
    def _read_lines(self) -> None:
        """Marlin reads serial only while the queue has room; the rest waits in the RX buffer."""
        while self._rx and len(self.queue) < BUFSIZE and not self.halted:
            cut = first_eol(self._rx)
            if cut < 0:  # a partial line: the reader keeps it until its end arrives
                chunk = bytes(self._rx)
                self._rx.clear()
            else:
                chunk = bytes(self._rx[: cut + 1])
                del self._rx[: cut + 1]
            for item in self.reader.feed(chunk):
                if isinstance(item, str):
                    self.write(item)
                    if "Resend:" in item:  # a line error clears the RX buffer
                        self._rx.clear()
                else:
                    self._take_line(item)

    def _take_line(self, line: Line) -> None:
        """A line passed the checks: emergency commands act now, then it is queued."""
        if line.emergency == "M108":
            self.wait_for_heatup = False
            if self.twin.board.autotune is not None:
                self.twin.board.cancel_autotune()
        elif line.emergency == "M112":
            self.twin.board.kill_m112()
            self.planner.clear()
            return
        elif line.emergency == "M410":
            self._quickstop()
        self.queue.append(line)

    def _quickstop(self) -> None:
        """quickstop_stepper() run by the read of an M410 line, inside the main loop's idle(): its
        planner.synchronize() holds the command that was executing until the cleaning window
        closes, and that command then looks again (an M400, G4 or G1 waiting on the moves goes on)."""
        self.planner.quickstop()
        if self.current is not None:
            self.wake_tick = self.twin.tick + (self.planner.ticks_to_next_change() or 0)

    def _dispatch(self) -> None:
        """Start queued commands while none is executing; instant ones finish at once."""
        self._read_lines()
        while self.current is None and self.queue and not self.halted:
            line = self.queue.popleft()
            try:
                self._start(parse(line.text))
            except Exception as exc:  # noqa: BLE001  a bug of the twin must not end the session
                self._internal_error(line.text, exc)
            self._read_lines()

    def _internal_error(self, text: str, exc: Exception) -> None:
        """A command raised: log it, answer as Marlin answers an error, carry on with the next."""
        LOG.exception("command %r raised", text)
        self.internal_errors += 1
        self.current = None
        self.idle_calls = True
        self.wait_for_heatup = False
        if not self.halted:
            self.write(f"Error:internal error in {text.strip()[:40]!r}: {type(exc).__name__}\nok\n")

    def _start(self, cmd: Command) -> None:
        handler = HANDLERS.get((cmd.letter, cmd.code)) if cmd.code is not None else None
        if handler is None:
            self.write(unknown_command_text(cmd))
            self.write("ok\n")
            return
        result = handler(self, cmd)
        if result is NO_OK:
            return
        if result is None:
            self.write("ok\n")
            return
        self.current = result
        self.keepalive_tick = self.after_ms(self.keepalive_s * 1000)
        self.keepalive_wall_s = self.wall_s() + self.keepalive_s
        self._resume()

    def _resume(self) -> None:
        """Run the executing command until it waits; when it ends, send its ok."""
        if self.current is None:
            return
        try:
            self.wake_tick = next(self.current)
        except StopIteration as stop:
            self.current = None
            if not self.halted and stop.value is not False:  # a command may send its own ok
                self.write("ok\n")
            self._dispatch()
        except Exception as exc:  # noqa: BLE001  a bug of the twin must not end the session
            self._internal_error("the executing command", exc)
            self._dispatch()

    def _wall_due(self, deadline_s: float) -> bool:
        return self.wall_clock is None or self.wall_clock() >= deadline_s

    def wall_s(self) -> float:
        """The transport's wall clock (0 when the printer is host-driven only)."""
        return self.wall_clock() if self.wall_clock is not None else 0.0

    def _run(self, end_tick: int, stop_when: Callable[[VirtualPrinter], bool] | None = None) -> None:
        twin = self.twin
        while twin.tick < end_tick:
            if self.halted:  # a dead board: the world goes on, nothing answers
                self.current, self.queue = None, deque()
                self.rx_dropped += self.link.in_flight
                self.link.clear()
                if stop_when is None:
                    twin.run_ticks(end_tick - twin.tick)
                return
            if self.current is None and not self.tx_blocked:
                self._dispatch()
            if stop_when is not None and stop_when(self):
                return
            target = min(end_tick, self._next_event_tick())
            self._advance(max(target, twin.tick) - twin.tick)
            self._take_arrivals()
            self._idle()
            if self.current is not None and twin.tick >= self.wake_tick and not self.halted:
                self._resume()

    def _next_event_tick(self) -> int:
        """The next tick something happens: a command wakes, a report is due, a block ends.

        A report due in virtual time but not yet in wall time is left to the next call
        (the transport calls again within its pacing step).
        """
        tick = self.twin.tick
        target = self.wake_tick if self.current is not None else _FAR
        if self.idle_calls:
            if self.current is not None and self.keepalive_s and self.keepalive_tick > tick:
                target = min(target, self.keepalive_tick)
            if self.autoreport_s and self.autoreport_tick > tick:
                target = min(target, self.autoreport_tick)
        change_ticks = self.planner.ticks_to_next_change()
        if change_ticks is not None:
            target = min(target, tick + change_ticks)
        arrival = self.link.next_line_tick()
        if arrival is not None and self._reads_lines:  # else arrivals wait for the next event (a full
            target = min(target, max(arrival, tick + 1))  # ring drops them then, as it would have)
        return target

    @property
    def _reads_lines(self) -> bool:
        """The main loop would take an arriving line now: the ring and the queue have room."""
        return not self.tx_blocked and len(self._rx) < RX_CAPACITY and len(self.queue) < BUFSIZE

    def _advance(self, n_ticks: int) -> None:
        if n_ticks <= 0:
            return
        self.twin.flow_mm_s = self.planner.flow_mm_s
        self.twin.run_ticks(n_ticks)
        self.planner.advance(n_ticks * TICK_S)
        self.twin.flow_mm_s = self.planner.flow_mm_s

    def _idle(self) -> None:
        """Marlin's idle(): M155 auto-report, then the busy keepalive while a command runs."""
        if self.halted or not self.idle_calls:
            return
        tick, wall_s = self.twin.tick, self.wall_s()
        if self.autoreport_s and tick >= self.autoreport_tick and self._wall_due(self.autoreport_wall_s):
            self.write(self.twin.board.heater_states() + "\n")
            self.autoreport_tick = self.after_ms(self.autoreport_s * 1000)
            self.autoreport_wall_s = wall_s + self.autoreport_s
        busy = self.current is not None and self.keepalive_s
        if busy and tick >= self.keepalive_tick and self._wall_due(self.keepalive_wall_s):
            self.write("echo:busy: processing\n")
            self.keepalive_tick = self.after_ms(self.keepalive_s * 1000)
            self.keepalive_wall_s = wall_s + self.keepalive_s


_FAR = 1 << 62  # no event: a tick no run reaches


def _idle_and_still(p: VirtualPrinter) -> bool:
    return p.current is None and not p.planner.blocks and not p.receiving


def _no_command(p: VirtualPrinter) -> bool:
    return p.current is None and not p.receiving
