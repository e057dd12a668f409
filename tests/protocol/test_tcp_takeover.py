"""Who may drive twin-serial --tcp (docs/serial.md, Connections): a newcomer takes the printer over
only from a host that has left it waiting --takeover-after seconds, or by sending the shared
secret; a stranger is refused with one Error: line; beyond loopback a secret or --allow-remote is
required."""

from __future__ import annotations

import select
import socket
import subprocess
import sys
import time

import pytest

from protocol.build import build_printer
from protocol.tcp_server import TcpServer, is_loopback
from tools.cli.serial import parse_args

START_TIMEOUT_S = 600  # hang guards (tests/helpers/serial_host.py)
READ_TIMEOUT_S = 300
SECRET = b"correct horse battery staple"


@pytest.fixture
def tcp_printer(spawn, tmp_path):
    """``tcp_printer(*flags)``: twin-serial --tcp on a free port with ``flags``; its (host, port)."""
    stderr_path = tmp_path / "stderr.txt"

    def start(*flags: str) -> tuple[str, int]:
        with open(stderr_path, "w") as stderr:
            proc = spawn([sys.executable, "-m", "tools.cli.serial", "--tcp", "127.0.0.1:0", *flags],
                         stdout=subprocess.PIPE, stderr=stderr, text=True)
        ready, _, _ = select.select([proc.stdout], [], [], START_TIMEOUT_S)
        assert ready, "twin-serial printed no address"
        host, port = proc.stdout.readline().strip().rsplit(":", 1)
        proc.stdout.close()
        return host, int(port)

    yield start
    assert "Traceback" not in stderr_path.read_text()


def _read_until(sock: socket.socket, marker: bytes, timeout_s: float = READ_TIMEOUT_S) -> bytes:
    """What arrives until ``marker`` (or the end of the stream, or the timeout)."""
    data = b""
    deadline = time.monotonic() + timeout_s
    while marker not in data and time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            chunk = sock.recv(4096)
        except TimeoutError:
            break
        if not chunk:
            break
        data += chunk
    return data


def _closed_by_printer(sock: socket.socket) -> bool:
    """The printer closed ``sock``: the stream ends (whatever was on its way is read first)."""
    _read_until(sock, b"\0")
    try:
        return sock.recv(4096) == b""
    except ConnectionResetError:
        return True


def _served(address, first: bytes = b"") -> socket.socket | None:
    """A connection that sends ``first`` then M105: open if the printer answers it, None if it was refused."""
    sock = socket.create_connection(address, timeout=READ_TIMEOUT_S)
    sock.sendall(first + b"M105\n")
    reply = _read_until(sock, b"ok T:")
    if b"ok T:" in reply:
        return sock
    assert reply.startswith(b"Error:") and _closed_by_printer(sock), reply
    sock.close()
    return None


@pytest.mark.slow
def test_a_host_that_left_the_printer_waiting_is_taken_over(tcp_printer):
    """A host that went silent without closing (crashed, or its link dropped) blocks the printer
    for --takeover-after seconds at most: then a newcomer gets it (a fresh board) and the old
    socket is closed."""
    address = tcp_printer("--takeover-after", "1")
    silent = socket.create_connection(address, timeout=READ_TIMEOUT_S)
    try:
        assert b"start" in _read_until(silent, b"start")  # it has the printer, then says nothing more
        deadline = time.monotonic() + READ_TIMEOUT_S
        newcomer = None
        while newcomer is None and time.monotonic() < deadline:
            newcomer = _served(address)  # refused while the silent host's second has not passed
            time.sleep(0.1)
        assert newcomer is not None, "no newcomer was served"
        newcomer.close()
        assert _closed_by_printer(silent)
    finally:
        silent.close()


@pytest.mark.slow
def test_a_stranger_cannot_take_over_a_host_that_is_printing(tcp_printer):
    """Neither from a host that talks (its M105 just now) nor from one that waits, silent, on its
    own command (G4 running at real time, longer than --takeover-after): the stranger gets one
    Error: line and is closed, and the host's print goes on on the same board."""
    address = tcp_printer("--speed", "1", "--takeover-after", "1")
    with socket.create_connection(address, timeout=READ_TIMEOUT_S) as host:
        host.sendall(b"G28\nG1 X100 F600\nM105\n")
        assert b"ok T:" in _read_until(host, b"ok T:")
        assert _served(address) is None  # it talked just now
        host.sendall(b"G4 S30\n")
        time.sleep(2)  # silent for twice --takeover-after, waiting for its G4
        assert _served(address) is None
        after = _read_until(host, b"\0", timeout_s=1)
        assert b"start" not in after  # not reset; still connected, still served (busy lines)
        assert b"echo:busy: processing" in after


@pytest.mark.slow
def test_with_a_secret_only_its_holders_are_served_and_the_newest_takes_over(tcp_printer, tmp_path):
    key = tmp_path / "key"
    key.write_bytes(SECRET + b"\n")
    address = tcp_printer("--secret-file", str(key))
    assert _served(address) is None  # no secret: M105 as the first line
    assert _served(address, b"not the secret\n") is None
    first = _served(address, SECRET + b"\n")
    assert first is not None
    with first:
        second = _served(address, SECRET + b"\r\n")  # takes over at once, though the first just talked
        assert second is not None
        second.close()
        assert _closed_by_printer(first)


def test_beyond_loopback_a_secret_or_allow_remote_is_required():
    printer = build_printer()
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("::")
    with pytest.raises(ValueError, match="listening on 0.0.0.0 lets any host .*--secret-file.*--allow-remote"):
        TcpServer(printer, host="0.0.0.0")
    for options in ({"secret": SECRET}, {"allow_remote": True}):
        TcpServer(printer, host="0.0.0.0", **options).close()


@pytest.mark.parametrize("content", [b"", b"\nsecret\n", b"x" * 300])
def test_a_secret_file_without_a_usable_first_line_is_one_line_and_exit_2(tmp_path, content, capsys):
    key = tmp_path / "key"
    key.write_bytes(content)
    with pytest.raises(SystemExit) as stop:
        parse_args(["--tcp", "127.0.0.1:0", "--secret-file", str(key)])
    assert stop.value.code == 2
    assert capsys.readouterr().err == (f"twin-serial: error: argument --secret-file: the first line of {key} must "
                                       "hold the secret, 1 to 256 bytes\n")
