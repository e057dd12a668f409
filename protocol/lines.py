"""Marlin 2.1's serial receive path (gcode/queue.cpp get_serial_commands): bytes in, lines out.

The reader splits the byte stream into command lines exactly as the firmware's line buffer does
(comments, backspace, escapes, the 95-character cut), checks line numbers and checksums, and
answers the errors itself, as Marlin does before a line ever reaches the command queue. What it
does not do is the queue: ``feed()`` consumes all of its data, so the caller, which knows when
the firmware's command queue (BUFSIZE 4) is full, decides when to feed.
"""

from __future__ import annotations

from dataclasses import dataclass

from firmware_port.fixed import wrap_s32
from protocol.gcode import strtol

MAX_CMD_SIZE = 96  # Configuration_adv.h: the line buffer; 95 characters and the NUL
STR_OK = "ok"  # core/language.h
STR_RESEND = "Resend: "
STR_ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
STR_ERR_CHECKSUM_MISMATCH = "checksum mismatch, Last Line: "
STR_ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "
STR_ERR_STOPPED = (
    "Printer stopped due to errors. Fix the error and use M999 to restart. "
    "(Temperature is reset. Set it after restarting)"
)
ERROR_START = "Error:"  # core/serial.cpp serial_error_start()
EMERGENCY_COMMANDS = ("M108", "M112", "M410")  # acted on at receive time without EMERGENCY_PARSER
STOPPED_MOVE_CODES = (0, 1, 2, 3)  # G0/G1, and G2/G3 as ARC_SUPPORT is on in the stock config

EOL_BYTES = b"\n\r"  # macros.h ISEOL()
BACKSPACE, BACKSLASH, SEMICOLON = 0x08, ord("\\"), ord(";")
PS_NORMAL, PS_EOL, PS_ESC = 0, 1, 4  # queue.cpp stream states (PAREN_COMMENTS and quotes off)


def checksum(text: str) -> int:
    """XOR of the line's bytes (one character per byte) before the ``*``."""
    cs = 0
    for byte in text.encode("latin-1"):
        cs ^= byte
    return cs


def with_checksum(line_without_n: str, n: int) -> str:
    """``N<n> <line>*<cs>``, framed as Printrun and OctoPrint send it (no newline)."""
    framed = f"N{n} {line_without_n}"
    return f"{framed}*{checksum(framed)}"


@dataclass(frozen=True)
class Line:
    """A line Marlin puts in its command queue."""

    text: str  # as enqueued: comment gone, cut at 95 chars and at a NUL, 'N..' and '*cs' kept
    number: int | None  # the checked N (for 'N.. M110 N<n>', that <n>); None on unnumbered lines
    emergency: str | None  # 'M108', 'M112' or 'M410' when the early check matches, else None


class LineReader:
    """One serial port's line buffer and line-number state (queue.cpp SerialState).

    ``ok_after_resend``: the default (True) sends ``ok`` after ``Resend: <n>``, as Marlin 2.1's
    GCodeQueue::flush_and_request_resend() does (``SERIAL_ECHOLNPGM(STR_OK)`` after the Resend
    line; earlier versions call ok_to_send() there, which prints it too). False leaves it out, a
    buggy firmware for testing a host's resend handling; see docs/serial.md.
    """

    def __init__(self, *, ok_after_resend: bool = True) -> None:
        self.ok_after_resend = ok_after_resend
        self.last_n = 0  # serial.last_N, int32; M110's handler sets it too
        self.stopped = False  # IsStopped(), set and cleared by the firmware (M999)
        self._buf = bytearray()  # serial.line_buffer up to serial.count
        self._state = PS_NORMAL  # serial.input_state

    def __repr__(self) -> str:
        return f"LineReader(last N{self.last_n}{', stopped' if self.stopped else ''}, {len(self._buf)} bytes buffered)"

    def reset(self) -> None:
        """A board reset: everything in RAM is back to its power-on value."""
        self.last_n = 0
        self.stopped = False
        self._buf.clear()
        self._state = PS_NORMAL

    def feed(self, data: bytes) -> list[Line | str]:
        """Read ``data``, what sat in the RX buffer, and return lines and replies in order.

        A reply is text to send at once, newlines included. After a line error Marlin empties
        the RX buffer, so the rest of ``data`` is dropped.
        """
        out: list[Line | str] = []
        for byte in data:
            if byte in EOL_BYTES:
                if self._line_done(out):
                    break
            else:
                self._stream_char(byte)
        return out

    def _stream_char(self, byte: int) -> None:
        """process_stream_char(): comment, escape, backspace and overflow handling."""
        if self._state == PS_EOL:  # in a ';' comment, or past 95 characters
            return
        if self._state == PS_ESC:  # the escaped character is kept as it is
            self._state = PS_NORMAL
        elif byte == BACKSLASH:
            self._state = PS_ESC
            return
        elif byte == SEMICOLON:
            self._state = PS_EOL
            return
        if byte == BACKSPACE:
            if self._buf:
                self._buf.pop()
        else:
            self._buf.append(byte)
            if len(self._buf) >= MAX_CMD_SIZE - 1:
                self._state = PS_EOL

    def _line_done(self, out: list[Line | str]) -> bool:
        """An end of line: check and enqueue it. True when an error emptied the RX buffer."""
        self._state = PS_NORMAL
        if not self._buf:  # an empty line: Marlin only runs the heater manager
            return False
        text = self._buf.split(b"\0", 1)[0].decode("latin-1")  # the C string ends at a NUL
        self._buf.clear()
        command = text.lstrip(" ")

        number = None
        if command.startswith("N"):  # numbers and checksums are checked only from a leading N
            m110 = "M110" in command
            npos = command.find("N", 4) if m110 else -1  # 'N.. M110 N<n>' sets the number to n
            number = strtol(command[max(npos, 0) + 1 :])
            if number != wrap_s32(self.last_n + 1) and not m110:
                if wrap_s32(self.last_n - 1) <= number <= self.last_n:
                    return False  # "A request-for-resend line was already in transit"
                return self._line_error(out, STR_ERR_LINE_NO)
            star = command.rfind("*")
            if star < 0:
                return self._line_error(out, STR_ERR_NO_CHECKSUM)
            if strtol(command[star + 1 :]) != checksum(command[:star]):
                return self._line_error(out, STR_ERR_CHECKSUM_MISMATCH)
            self.last_n = number

        if self.stopped:  # Marlin looks for the first 'G' anywhere in the line
            gpos = command.find("G")
            if gpos >= 0 and strtol(command[gpos + 1 :]) in STOPPED_MOVE_CODES:
                out.append(STR_ERR_STOPPED + "\n")

        # RingBuffer::enqueue() refuses a line starting with ';' (only an escaped one can).
        # A line of spaces (maybe before a comment) is dropped here without an ok; Marlin
        # itself enqueues it and answers 'echo:Unknown command: ""' and 'ok'.
        if text.startswith(";") or not command:
            return False
        emergency = command[:4] if command[:4] in EMERGENCY_COMMANDS else None
        out.append(Line(text, number, emergency))
        return False

    def _line_error(self, out: list[Line | str], message: str) -> bool:
        """gcode_line_error() and flush_and_request_resend()."""
        reply = f"{ERROR_START}{message}{self.last_n}\n{STR_RESEND}{wrap_s32(self.last_n + 1)}\n"
        if self.ok_after_resend:
            reply += STR_OK + "\n"
        out.append(reply)
        return True
