"""A real OctoPrint against twin-serial, for the tests that drive it (tests/protocol/test_octoprint.py,
tests/octoprint_plugin): twin-serial on a pty, OctoPrint headless on 127.0.0.1 with a throwaway basedir
and a global API key written into its config.yaml, its REST API, and its push API for the terminal's
lines. Processes are started with the ``spawn`` fixture (always stopped); every wait has a timeout.
"""

from __future__ import annotations

import asyncio
import contextlib
import http.client
import importlib.util
import json
import os
import secrets
import select
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.conftest import unavailable
from tests.helpers.serial_host import START_TIMEOUT_S as SERIAL_START_TIMEOUT_S

# Hang guards, not timings (a busy 2-core machine is many times slower than a quiet one: tests/helpers/serial_host.py)
START_TIMEOUT_S = 900  # OctoPrint's first start compiles its assets and loads its plugins (about a minute when quiet)
CONNECT_TIMEOUT_S = 300
HTTP_TIMEOUT_S = 120  # one request; wait_for asks again until its own bound
TERMINAL_TIMEOUT_S = 300  # commands sent from the terminal, their reply read back
# OctoPrint's plugins that phone home or need hardware: off, so the test needs no network.
DISABLED_PLUGINS = ["announcements", "softwareupdate", "tracking", "pluginmanager", "achievements", "pi_support",
                    "discovery", "errortracking", "backup", "virtual_printer", "health_check"]


def require_octoprint() -> None:
    if importlib.util.find_spec("octoprint") is None:
        unavailable("OctoPrint is not installed: pip install -e '.[octoprint]' (.ci/run installs it)")


def state_text(reply: dict) -> str:
    """The printer's state as /api/job, /api/connection or /api/printer gives it ('' if none)."""
    state = reply.get("state", reply.get("current", {}).get("state", ""))
    return state.get("text", "") if isinstance(state, dict) else str(state)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class OctoPrint:
    """The REST API of a running server, with the key from its config.yaml."""

    def __init__(self, port: int, api_key: str):
        self.port = port
        self.base = f"http://127.0.0.1:{port}"
        self.api_key = api_key

    def request(self, method: str, path: str, body: dict | None = None, *, data: bytes | None = None,
                content_type: str = "application/json") -> dict:
        if body is not None:
            data = json.dumps(body).encode()
        request = urllib.request.Request(self.base + path, data=data, method=method,
                                         headers={"X-Api-Key": self.api_key, "Content-Type": content_type})
        with urllib.request.urlopen(request, timeout=HTTP_TIMEOUT_S) as reply:
            text = reply.read().decode()
        return json.loads(text) if text else {}

    def upload_and_print(self, name: str, text: str) -> None:
        boundary = uuid.uuid4().hex
        parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
                 f"Content-Type: application/octet-stream\r\n\r\n{text}\r\n"]
        parts += [f'--{boundary}\r\nContent-Disposition: form-data; name="{field}"\r\n\r\ntrue\r\n'
                  for field in ("select", "print")]
        data = ("".join(parts) + f"--{boundary}--\r\n").encode()
        self.request("POST", "/api/files/local", data=data, content_type=f"multipart/form-data; boundary={boundary}")

    def wait_for(self, what: str, test: Callable[[dict], bool], timeout_s: float, path: str) -> dict:
        """Poll ``path`` until ``test(reply)``; fail naming ``what`` and the last reply."""
        deadline = time.monotonic() + timeout_s
        reply: dict = {}
        while time.monotonic() < deadline:
            try:
                reply = self.request("GET", path)
            except (urllib.error.URLError, http.client.HTTPException, ConnectionError, TimeoutError):
                reply = {}  # not up yet (OctoPrint's intermediary server answers while it starts)
            if reply and test(reply):
                return reply
            state = state_text(reply)
            assert "error" not in state.lower(), f"{what}: OctoPrint reports {state!r}"
            time.sleep(0.5)
        pytest.fail(f"{what}: not within {timeout_s} s; last {path}: {reply}")

    def connect(self, link: Path) -> None:
        """Connect OctoPrint to the printer at ``link`` and wait until it is operational."""
        self.request("POST", "/api/connection", {"command": "connect", "port": str(link), "baudrate": 115200})
        self.wait_for("the connection", lambda reply: reply["current"]["state"] == "Operational", CONNECT_TIMEOUT_S,
                      "/api/connection")

    def add_user(self, name: str, password: str) -> None:
        """An administrator that a browser logs in as."""
        self.request("POST", "/api/access/users", {"name": name, "password": password, "active": True,
                                                   "groups": ["admins", "users"]})

    def terminal(self, commands: list[str], until: Callable[[list[str]], bool], user: tuple[str, str]) -> list[str]:
        """Send ``commands`` as the terminal does and return the terminal's lines (``Send: ``/``Recv: ``) from
        then on, read through the push API as ``user`` (name, password), once ``until(lines)``."""
        session = self.request("POST", "/api/login", {"user": user[0], "pass": user[1]})["session"]
        return asyncio.run(asyncio.wait_for(self._terminal(commands, until, f"{user[0]}:{session}"),
                                            TERMINAL_TIMEOUT_S))

    async def _terminal(self, commands: list[str], until: Callable[[list[str]], bool], auth: str) -> list[str]:
        from tornado.websocket import websocket_connect  # OctoPrint's own dependency

        conn = await websocket_connect(f"ws://127.0.0.1:{self.port}/sockjs/websocket")
        try:
            await conn.write_message(json.dumps({"auth": auth}))
            lines: list[str] = []
            sent = False
            while not (sent and until(lines)):
                message = await conn.read_message()
                assert message is not None, "OctoPrint closed the push API's socket"
                current = json.loads(message).get("current")
                if current is None:
                    continue
                if not sent:  # the first report after the login: from here on the lines are ours
                    self.request("POST", "/api/printer/command", {"commands": commands})
                    sent = True
                    continue
                lines += current.get("logs", [])
            return lines
        finally:
            conn.close()


@contextlib.contextmanager
def twin_printer(tmp_path: Path, spawn, idle_speed: float, speed: str = "max") -> Iterator[Path]:
    """twin-serial on a pty behind tmp_path/printer: the default stock printer (stopped by ``spawn``), its clock at
    ``speed`` while a command runs (twin-serial's --speed); on exit, its stderr must hold no traceback."""
    link = tmp_path / "printer"
    stderr_path = tmp_path / "twin-serial.stderr"
    with open(stderr_path, "w") as stderr:
        proc = spawn([sys.executable, "-m", "tools.cli.serial", "--link", str(link), "--idle-speed", str(idle_speed),
                      "--speed", speed],
                     stdout=subprocess.PIPE, stderr=stderr, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], SERIAL_START_TIMEOUT_S)
    assert ready and proc.stdout.readline().strip(), "twin-serial printed no port"
    yield link
    proc.stdout.close()
    assert "Traceback" not in stderr_path.read_text()


def start_octoprint(tmp_path: Path, link: Path, spawn, plugins: dict | None = None) -> OctoPrint:
    """OctoPrint serving on a free port of 127.0.0.1, ``link`` among its serial ports; ``plugins`` adds
    plugins' settings to its config.yaml. Returns once its API answers."""
    require_octoprint()
    basedir = tmp_path / "octoprint"
    basedir.mkdir()
    api_key = secrets.token_hex(16)
    config = {
        "api": {"key": api_key},
        "server": {"firstRun": False, "onlineCheck": {"enabled": False}, "pluginBlacklist": {"enabled": False}},
        "serial": {"additionalPorts": [str(link)], "autoconnect": False},
        "plugins": {"_disabled": DISABLED_PLUGINS, **(plugins or {})},
    }
    (basedir / "config.yaml").write_text(json.dumps(config))  # JSON is YAML
    port = free_port()
    args = [sys.executable, "-m", "octoprint", "serve", "--host", "127.0.0.1", "--port", str(port),
            "--basedir", str(basedir)]
    if os.geteuid() == 0:
        args.append("--iknowwhatimdoing")  # OctoPrint refuses root without it
    with open(tmp_path / "octoprint.out", "w") as log:
        spawn(args, stdout=log, stderr=subprocess.STDOUT)  # OctoPrint's log, for a failure's post-mortem
    server = OctoPrint(port, api_key)
    server.wait_for("the server", lambda reply: "api" in reply, START_TIMEOUT_S, "/api/version")
    return server
