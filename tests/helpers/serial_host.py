"""twin-serial as a host sees it: run it as a process (``twin_serial``) and read its replies with a
timeout (``expect``); shared by the serial tests under tests/protocol.

The bounds are hang guards, not timings: on a busy 2-core machine (load 10 to 40) a start that takes 2 s
when quiet took over a minute, so a server's readiness (the line it prints) is waited for for minutes, and
so is a reply. Each read on a port stays short (READ_TIMEOUT_S), so no read hangs."""

from __future__ import annotations

import contextlib
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

ROOT = Path(__file__).resolve().parents[2]  # tests/helpers/ -> the repository
CLI = [sys.executable, "-m", "tools.cli.serial"]
START_TIMEOUT_S = 600  # a server's first line: interpreter start and imports, seconds when quiet
READ_TIMEOUT_S = 5  # one read on a port; ``expect`` reads again until its own bound
REPLY_TIMEOUT_S = 300  # ``expect``'s bound on a reply: milliseconds when quiet


@contextlib.contextmanager
def twin_serial(*args: str, tmp_path: Path):
    """Run twin-serial; yield the process and the address it printed; always stop it."""
    with open(tmp_path / "stderr.txt", "w+") as stderr:
        proc = subprocess.Popen([*CLI, *args], stdout=subprocess.PIPE, stderr=stderr, text=True, cwd=ROOT)
        try:
            ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
            address = proc.stdout.readline().strip() if ready else ""
            if not address:
                stderr.seek(0)
                pytest.fail(f"twin-serial printed no address; stderr: {stderr.read()}")
            yield proc, address
        finally:
            if proc.poll() is None:
                proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()


def expect(port: serial.SerialBase, pattern: str, timeout_s: float = REPLY_TIMEOUT_S) -> list[str]:
    """Read lines until one matches ``pattern``; the lines read, the match last."""
    seen: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = port.readline().decode("latin-1").rstrip("\n")
        if line:
            seen.append(line)
            if re.search(pattern, line):
                return seen
    pytest.fail(f"no line matching {pattern!r} within {timeout_s} s; got {seen}")
