"""A TCP client that goes silent without closing does not block the next one: the newcomer takes
the printer over, as a USB re-plug does (docs/serial.md)."""

from __future__ import annotations

import select
import socket
import subprocess
import sys
import time

import pytest

START_TIMEOUT_S = 60
READ_TIMEOUT_S = 30


@pytest.fixture
def tcp_printer(spawn, tmp_path):
    """twin-serial --tcp on a free port: its address (stopped at teardown by ``spawn``)."""
    stderr_path = tmp_path / "stderr.txt"
    with open(stderr_path, "w") as stderr:
        proc = spawn([sys.executable, "-m", "tools.cli.serial", "--tcp", "127.0.0.1:0"],
                     stdout=subprocess.PIPE, stderr=stderr, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
    assert ready, "twin-serial printed no address"
    host, port = proc.stdout.readline().strip().rsplit(":", 1)
    yield host, int(port)
    proc.stdout.close()
    assert "Traceback" not in stderr_path.read_text()


def _read_until(sock: socket.socket, marker: bytes) -> bytes:
    data = b""
    deadline = time.monotonic() + READ_TIMEOUT_S
    while marker not in data and time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return data


@pytest.mark.slow


def test_a_new_connection_takes_over_from_a_silent_one(tcp_printer):
    silent = socket.create_connection(tcp_printer, timeout=READ_TIMEOUT_S)
    try:
        assert b"start" in _read_until(silent, b"start")  # it has the printer, then says nothing more
        with socket.create_connection(tcp_printer, timeout=READ_TIMEOUT_S) as newcomer:
            newcomer.sendall(b"M105\n")
            assert b"ok T:" in _read_until(newcomer, b"ok T:")  # served: a fresh board, its banner first
        _read_until(silent, b"\0")  # whatever was on its way, up to the end of the stream
        assert silent.recv(4096) == b""  # the printer closed it
    finally:
        silent.close()
