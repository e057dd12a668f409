"""A Marlin 2.1 printer on a serial line: bytes in, Marlin's replies out, a twin underneath.

``VirtualPrinter`` is what a transport (pty, TCP, the pyserial URL handler) talks to. It keeps
Marlin's RX line layer and command queue (BUFSIZE 4), runs one command at a time, and owns the
twin's clock: a command that takes time (M109, M190, M303, G4, M400, a G1 into a full planner)
is a generator that yields the tick it wants to be resumed at, and the clock runs to it while
Marlin's idle() duties happen on the way (busy keepalive every 2 s, M155 auto-reports).

The transport decides how fast virtual time passes: ``run_for(seconds)`` for a speed of N x real
time, ``run_until_idle()`` for ``--speed max`` (run free while a command executes, stop when
the printer waits for the host).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Generator

from firmware_port.marlin.constants import ms_to_ticks, ticks_to_ms
from protocol.commands import HANDLERS, NO_OK, banner
from protocol.gcode import Command, parse, unknown_command_text
from protocol.lines import Line, LineReader
from protocol.planner import Planner
from protocol.settings import Eeprom
from twin.engine import Twin
from twin.linear import TICK_S

BUFSIZE = 4  # Marlin's command ring buffer
DEFAULT_KEEPALIVE_S = 2  # DEFAULT_KEEPALIVE_INTERVAL
TICKS_PER_S = 1.0 / TICK_S
BOOT_TICKS = round(1.0 * TICKS_PER_S)  # from reset to the host's first command: readings are in

Task = Generator[int, None, None]  # yields the absolute tick to be resumed at


class VirtualPrinter:
    """Marlin's serial front end and command loop over a twin."""

    def __init__(self, make_twin: Callable[[], Twin], *, eeprom: Eeprom | None = None, ok_after_resend: bool = False):
        self.twin = make_twin()
        self.twin.recording = False  # a serial session can run for days: no trace rows
        self.eeprom = eeprom if eeprom is not None else Eeprom()
        self.reader = LineReader(ok_after_resend=ok_after_resend)
        self._out = bytearray()
        self.twin.console.listeners.append(lambda text: self._out.extend(text.encode("latin-1")))
        self._boots = 0
        self.reset()

    # -- what a transport uses ------------------------------------------------------------
    def reset(self) -> None:
        """Reset the board (DTR toggle, new connection): the banner, settings from the EEPROM."""
        self.twin.reset_board()
        self.reader.reset()
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
        self.write(banner(self, power_up=self._boots == 0))
        self._boots += 1
        self.twin.run_ticks(BOOT_TICKS)  # setup() finishes; the first readings come in
        self.twin.origin_tick = self.twin.tick  # time_s counts from here

    def receive(self, data: bytes) -> None:
        """Bytes from the host; lines are taken into the queue as it has room (Marlin's RX)."""
        if self.halted:
            return
        self._rx.extend(data)
        self._read_lines()
        self._dispatch()

    def take_output(self) -> bytes:
        """Everything printed since the last call."""
        data = bytes(self._out)
        self._out.clear()
        return data

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
        """``--speed max``: run free while a command executes, stop when waiting for the host."""
        self._run(self.twin.tick + round(max_seconds * TICKS_PER_S), stop_when_idle=True)

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
            cut = _first_eol(self._rx)
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
        self.queue.append(line)

    def _dispatch(self) -> None:
        """Start queued commands while none is executing; instant ones finish at once."""
        while self.current is None and self.queue and not self.halted:
            line = self.queue.popleft()
            self._start(parse(line.text))
            self._read_lines()

    def _start(self, cmd: Command) -> None:
        handler = HANDLERS.get((cmd.letter, cmd.code))
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
        self._resume()

    def _resume(self) -> None:
        """Run the executing command until it waits; when it ends, send its ok."""
        try:
            self.wake_tick = next(self.current)
        except StopIteration as stop:
            self.current = None
            if not self.halted and stop.value is not False:  # a command may send its own ok
                self.write("ok\n")
            self._dispatch()

    def _run(self, end_tick: int, stop_when_idle: bool = False) -> None:
        twin = self.twin
        while twin.tick < end_tick:
            if self.halted:  # a dead board: the world goes on, nothing answers
                self.current, self.queue = None, deque()
                if not stop_when_idle:
                    twin.run_ticks(end_tick - twin.tick)
                return
            if self.current is None:
                self._dispatch()
            if self.current is None and stop_when_idle and not self.planner.blocks:
                return
            target = end_tick
            if self.current is not None:
                target = min(target, self.wake_tick)
            if self.idle_calls:
                if self.current is not None and self.keepalive_s:
                    target = min(target, self.keepalive_tick)
                if self.autoreport_s:
                    target = min(target, self.autoreport_tick)
            change_s = self.planner.time_to_next_change_s()
            if change_s is not None:
                target = min(target, twin.tick + max(1, round(change_s * TICKS_PER_S)))
            self._advance(max(target, twin.tick) - twin.tick)
            self._idle()
            if self.current is not None and twin.tick >= self.wake_tick and not self.halted:
                self._resume()

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
        tick = self.twin.tick
        if self.autoreport_s and tick >= self.autoreport_tick:
            self.write(self.twin.board.heater_states() + "\n")
            self.autoreport_tick = self.after_ms(self.autoreport_s * 1000)
        if self.current is not None and self.keepalive_s and tick >= self.keepalive_tick:
            self.write("echo:busy: processing\n")
            self.keepalive_tick = self.after_ms(self.keepalive_s * 1000)


def _first_eol(data: bytearray) -> int:
    """Index of the first CR or LF, or -1."""
    positions = [p for p in (data.find(b"\n"), data.find(b"\r")) if p >= 0]
    return min(positions) if positions else -1
