"""The fuzzer (tests/helpers/serial_fuzz.py) against the printer: no exit, no traceback, Marlin's replies.

Over twin:// (in process, host-driven clock so a seed gives the same session) FUZZ_LINES lines,
20 000 by default to keep CI short; the nightly-sized run is
``FUZZ_LINES=100000 python -m pytest tests/protocol/test_fuzz_serial.py -q`` (see docs/serial.md). Over a
pty, the twin-serial process itself gets a smaller run. The host is a patient but not endless
one: after each line it reads until the printer is idle or has run FREE_STEPS_PER_LINE virtual
seconds, then resets the board (DTR) if a command still runs or the board was killed, as a host
that times out reconnects.

The twin:// run also bounds the process's memory: its resident size may grow by at most
RSS_GROWTH_BOUND_MB over the session, whatever its length (the plant caches are bounded:
twin/linear.py; docs/serial.md states the bound and the 10^5-line measurement).
"""

from __future__ import annotations

import copy
import logging
import os
import select
import time

import pytest
import serial

import protocol  # noqa: F401  registers twin://
from protocol.build import build_printer
from tests.helpers.serial_fuzz import bad_replies, fuzz_lines
from tests.helpers.serial_host import REPLY_TIMEOUT_S, twin_serial

FUZZ_LINES = int(os.environ.get("FUZZ_LINES", "20000"))
# Two plants x MAX_CACHED_MODELS (8) x MAX_CACHED_RUNS (48) maps of up to ~45 kB: 35 MB at most,
# and slack for the allocator. Measured: +7 MB over 10^5 lines (docs/serial.md).
RSS_GROWTH_BOUND_MB = 48
PTY_FUZZ_LINES = 1500
FREE_STEPS_PER_LINE = 3  # virtual seconds a line may run before the host gives up on it
SEED = 20261123


def _exchange(port, line: bytes) -> tuple[str, bool]:
    """Send one line, read what comes while its command runs (a bounded time); its output and
    whether the host had to reset the board."""
    printer = port.printer
    port.write(line)
    out = port.read(port.in_waiting)
    for _ in range(FREE_STEPS_PER_LINE):
        if not printer.executing:
            break
        out += port.read(max(1, port.in_waiting))
    out += port.read(port.in_waiting)
    reset = printer.executing or printer.halted
    if reset:
        port.dtr = False
        port.dtr = True
        port.reset_input_buffer()
    return out.decode("latin-1"), reset


def rss_mb() -> float:
    """This process's resident set (Linux /proc), MB."""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS:")) / 1024


@pytest.mark.parametrize("command", ["M303 E0 S210 C3 U1", "M303 E-1 S60 C3"])
def test_the_reply_shapes_cover_a_whole_autotune_report(command):
    """A fuzzed line can start an M303 that finishes: its report (hotend "Classic PID", bed "No
    overshoot") is Marlin's, so the shape list has to know every line of it."""
    printer = build_printer()
    printer.take_output()
    printer.receive(command.encode() + b"\n")
    printer.run_until_idle(3600)
    report = printer.take_output().decode()
    assert "PID Autotune finished" in report
    assert bad_replies(report) == []


@pytest.mark.slow


def test_fuzzed_lines_over_twin_url_get_marlin_replies_only(caplog):
    caplog.set_level(logging.ERROR)
    unanswered, shapes, resets = [], [], 0
    with serial.serial_for_url("twin://?speed=max&idle_speed=0", timeout=0) as port:
        port.reset_input_buffer()
        start_mb = rss_mb()
        for line in fuzz_lines(SEED, FUZZ_LINES):
            printer = port.printer
            was_idle = not printer.executing and not printer.queue
            expected = copy.deepcopy(printer.reader).feed(line)  # what Marlin's line layer makes of it
            text, reset = _exchange(port, line)
            resets += reset
            shapes += bad_replies(text)
            # A line taken into an idle printer is answered with ok (an error too, after its
            # Resend), unless Marlin is silent about it (comment, empty, duplicate number) or it
            # still runs or killed the board, which the host's reset covers.
            answered = any(reply.startswith("ok") for reply in text.split("\n"))
            if was_idle and expected and not reset and not answered:
                unanswered.append((line, text))
        internal_errors = port.printer.internal_errors
        growth_mb = rss_mb() - start_mb
    print(f"resident memory: {start_mb:.1f} MB at the start, grew {growth_mb:.1f} MB over {FUZZ_LINES} lines")
    assert shapes == []
    assert unanswered == []
    assert internal_errors == 0 and caplog.records == []  # no command raised
    assert resets < FUZZ_LINES / 10  # the host mostly got its answers without a reset
    assert growth_mb < RSS_GROWTH_BOUND_MB


@pytest.mark.slow


def test_fuzzed_lines_over_a_pty_never_stop_the_server(tmp_path):
    """The twin-serial process: it survives the lines, answers each as Marlin would, logs nothing."""
    with twin_serial("--idle-speed", "0", tmp_path=tmp_path) as (proc, path):
        with serial.Serial(path, 115200, timeout=REPLY_TIMEOUT_S) as port:  # a hang guard: reads end at the marks
            port.write(b"M105\n")
            banner = port.read_until(b"ok T:") + port.read_until(b"\n")
            assert b"start" in banner
            port.timeout = 0.5
            received = bytearray()
            for line in fuzz_lines(SEED + 1, PTY_FUZZ_LINES):
                if b"M112" in line or proc.poll() is not None:
                    continue  # a kill needs a reconnect; the twin:// run covers it
                port.write(line)
                deadline = time.monotonic() + 0.02
                while time.monotonic() < deadline:
                    ready, _, _ = select.select([port.fileno()], [], [], 0.005)
                    if ready:
                        received += port.read(port.in_waiting or 1)
        assert proc.poll() is None, "twin-serial exited"
        with serial.Serial(path, 115200, timeout=REPLY_TIMEOUT_S) as port:  # a command may still run: reconnect
            port.write(b"M105\n")
            tail = port.read_until(b"ok T:")
        assert b"ok T:" in tail  # still serving after all of that
        received += tail
    assert bad_replies(received.decode("latin-1")) == []
    stderr = (tmp_path / "stderr.txt").read_text()
    assert "Traceback" not in stderr and "ERROR" not in stderr
