"""``twin://``: a printer twin in this process behind pyserial's API (no pty, no thread).

    import protocol  # registers the handler with pyserial
    import serial
    port = serial.serial_for_url("twin://?firmware=pid&speed=max", timeout=2)

Query parameters (all optional): firmware, plant, bed_plant (``none``: a hotend-only board),
scenario (preset name or TOML file), speed (the clock while a command executes: ``max``, the
default, or N x real time), idle_speed (the clock while the printer waits for the host: N x real
time, 1 by default under ``speed=max``; 0 stops it, the deterministic host-driven clock), settings
(the EEPROM file M500 writes), ok_after_resend (``1``, the default, or ``0``). The virtual clock
advances when the caller reads, writes or asks for ``in_waiting`` (see ``transport.Pacer``); at
``max`` a command runs up to a virtual second each time the received output has run out.
Output the caller leaves unread beyond HOST_BUFFER_BYTES stalls the printer's main loop as a
full TX buffer stalls Marlin. Asserting DTR again (``port.dtr = False; port.dtr = True``) resets
the board.
"""

from __future__ import annotations

import time
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, Timeout, to_bytes

from protocol.build import build_printer
from protocol.pacing import Pacer, parse_idle_speed, parse_speed
from protocol.server import HOST_BUFFER_BYTES

PARAMETERS = ("firmware", "plant", "bed_plant", "scenario", "speed", "idle_speed", "settings", "ok_after_resend")
FLAGS = {"": True, "1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}
URL_FORM = "twin://?firmware=pid&speed=max (parameters: " + ", ".join(PARAMETERS) + ")"


def parse_url(url: str) -> dict[str, str]:
    """The query parameters of a ``twin://`` URL; SerialException names what is wrong."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme.lower() != "twin" or parts.netloc or parts.path not in ("", "/"):
        raise SerialException(f"{url!r}: expected {URL_FORM}")
    pairs = urllib.parse.parse_qsl(parts.query, keep_blank_values=True)
    unknown = sorted({key for key, _ in pairs} - set(PARAMETERS))
    if unknown:
        raise SerialException(f"{url!r}: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(PARAMETERS)}")
    twice = sorted({key for key, _ in pairs if sum(k == key for k, _ in pairs) > 1})
    if twice:
        raise SerialException(f"{url!r}: parameter(s) given twice: {', '.join(twice)}")
    return dict(pairs)


class Serial(SerialBase):
    """A VirtualPrinter (``.printer`` once open) with pyserial's Serial API; any baud rate goes."""

    is_open: bool  # SerialBase's, set in its __init__

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        options = parse_url(self.portstr)
        try:
            speed = parse_speed(options.get("speed", "max"))
            idle_speed = parse_idle_speed(options["idle_speed"]) if "idle_speed" in options else None
            ok_after_resend = FLAGS.get(options.get("ok_after_resend", "1").lower())
            if ok_after_resend is None:
                raise ValueError(f"ok_after_resend must be 1 or 0, not {options['ok_after_resend']!r}")
            bed_plant = options.get("bed_plant")
            self.printer = build_printer(
                firmware=options.get("firmware", "pid"), plant=options.get("plant"),
                bed_plant=None if bed_plant == "none" else bed_plant, with_bed=bed_plant != "none",
                scenario=options.get("scenario"), settings=options.get("settings"),
                ok_after_resend=ok_after_resend,
            )
        except ValueError as exc:
            raise SerialException(f"{self.portstr!r}: {exc}") from exc
        self._pacer = Pacer(self.printer, speed, idle_speed)
        self._received = bytearray()  # the printer's output, not yet read
        self._dtr_asserted = self._dtr_state
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self) -> None:
        """Baud rate, parity and the rest mean nothing to a virtual wire."""

    # -- data -------------------------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        self._check_open()
        if not self._pacer.host_driven or not self._received:  # host-driven, the clock waits for the reader
            self._pump()
        return len(self._received)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes; waits (running the clock) until they come or the timeout ends."""
        self._check_open()
        timeout = Timeout(self._timeout)
        while len(self._received) < size:
            wait_s = self._pump()
            if len(self._received) >= size or timeout.expired():
                break
            if wait_s is None:  # host-driven and idle: nothing comes until the host writes
                if timeout.is_infinite:
                    raise SerialException("twin:// read would wait forever: the printer is idle at speed "
                                          "max and waits for the host (set a read timeout)")
                time.sleep(timeout.time_left())
                break
            time.sleep(wait_s if timeout.is_infinite else min(wait_s, timeout.time_left()))
        data = bytes(self._received[:size])
        del self._received[:size]
        return data

    def write(self, data: bytes) -> int:
        """Hand the bytes to the printer (at speed N, once its clock has caught up)."""
        self._check_open()
        data = to_bytes(data)
        if not self._pacer.host_driven:
            self._pump()
        self._note_tx()
        self.printer.receive(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        self._check_open()
        self._received.clear()
        self.printer.take_output()

    def reset_output_buffer(self) -> None:
        """Nothing waits on the way out: write() hands bytes straight to the printer."""
        self._check_open()

    @property
    def out_waiting(self) -> int:
        self._check_open()
        return 0

    # -- modem lines ------------------------------------------------------------------------
    def _update_dtr_state(self) -> None:
        """Asserting DTR resets the board, as the auto-reset capacitor of an Arduino does."""
        if self._dtr_state and not self._dtr_asserted:
            self.printer.reset()
        self._dtr_asserted = self._dtr_state

    def _update_rts_state(self) -> None:
        """RTS is not wired."""

    def _update_break_state(self) -> None:
        """A break means nothing to Marlin."""

    @property
    def cts(self) -> bool:
        self._check_open()
        return True

    @property
    def dsr(self) -> bool:
        self._check_open()
        return True

    @property
    def ri(self) -> bool:
        self._check_open()
        return False

    @property
    def cd(self) -> bool:
        self._check_open()
        return True

    # -- the clock --------------------------------------------------------------------------
    def _pump(self) -> float | None:
        """Let virtual time pass as the speed says, collect the output; return the pacer's wait.

        A paced clock catches up with the wall clock in full; a free one runs one step at most.
        """
        self._note_tx()
        wait_s = self._pacer.advance()
        while wait_s == 0.0 and not self._pacer.runs_free:
            wait_s = self._pacer.advance()
        self._received += self.printer.take_output()
        return wait_s

    def _note_tx(self) -> None:
        """Output the caller leaves unread beyond HOST_BUFFER_BYTES stalls Marlin's main loop."""
        self.printer.tx_blocked = len(self._received) + self.printer.output_waiting >= HOST_BUFFER_BYTES

    def _check_open(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
