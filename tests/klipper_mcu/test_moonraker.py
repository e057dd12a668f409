"""Moonraker (0.11.0, from its own venv: $HEATER_TWIN_MOONRAKER_VENV, else .venv-moonraker) on top
of klippy on the twin MCU: a target set through its HTTP API (/printer/gcode/script) heats the
twin, as /printer/objects/query and /server/gcode_store show. Loopback only; announcements off
(no feed fetched); every request and wait has a timeout."""

from __future__ import annotations

import json
import socket
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request

import pytest

from tests.conftest import unavailable
from tools.klipper_host.session import MOONRAKER_VENV_ENV, Missing, venv_command

pytestmark = pytest.mark.slow

HTTP_TIMEOUT_S = 120
START_TIMEOUT_S = 900
HOTEND = "heater_generic hotend"
CONFIG = """[server]
host: 127.0.0.1
port: {port}
klippy_uds_address: {socket}

[machine]
provider: none

[authorization]
trusted_clients:
    127.0.0.0/8

[announcements]
enable_moonlight: False
"""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def http(url: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=HTTP_TIMEOUT_S) as reply:
        return json.load(reply)["result"]


@pytest.fixture
def moonraker(klipper):
    try:
        command = venv_command(MOONRAKER_VENV_ENV)
    except Missing as exc:
        unavailable(str(exc))
    return klipper.fixture("the moonraker fixture",
                           lambda: start_moonraker(command, klipper(), klipper.spawn, START_TIMEOUT_S))


def start_moonraker(command, session, spawn, guard_s: float) -> str:
    """Moonraker on a free port, its files in the session's folder, on the session's klippy socket; its base
    URL once it sees klippy ready. It fails at once if Moonraker sees klippy shut down or in error (final: no
    one restarts it here), and after ``guard_s`` without progress (a new answer, or Moonraker's log growing)."""
    folder = session.workdir
    port = free_port()
    (folder / "moonraker.conf").write_text(CONFIG.format(port=port, socket=session.api_path))
    with open(folder / "moonraker.out", "w") as out:
        proc = spawn([str(command), "-d", str(folder / "data"), "-c", str(folder / "moonraker.conf"),
                      "-l", str(folder / "moonraker.log")], stdout=out, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    seen, deadline = None, 0.0
    while (state := klippy_state(base)) != "ready":
        assert proc.poll() is None, (folder / "moonraker.out").read_text()
        assert state.split(":")[0] not in ("shutdown", "error"), f"Moonraker sees klippy {state}"
        progress = state, sum(path.stat().st_size for path in folder.glob("moonraker.*") if path.is_file())
        if progress != seen:
            seen, deadline = progress, time.monotonic() + guard_s
        assert time.monotonic() < deadline, f"Moonraker never saw klippy ready: {state}, nothing new for {guard_s:g} s"
        time.sleep(0.2)
    return base


def klippy_state(base: str) -> str:
    """klippy's state as Moonraker says it (``ready``, ``startup``, ``shutdown: its message``), or why Moonraker
    gave none."""
    try:
        info = http(base + "/printer/info")
    except (OSError, urllib.error.URLError, KeyError) as exc:
        return f"no answer ({exc})"
    message = info.get("state_message", "").strip()
    return info.get("state", "") + (f": {message}" if info.get("state") != "ready" and message else "")


def test_moonraker_sets_a_target_and_the_twin_heats(moonraker):
    assert http(moonraker + "/printer/gcode/script", {"script": "SET_HEATER_TEMPERATURE HEATER=hotend TARGET=150"}) \
        == "ok"
    query = moonraker + "/printer/objects/query?" + urllib.parse.quote(HOTEND)
    deadline = time.monotonic() + START_TIMEOUT_S
    while (status := http(query)["status"][HOTEND])["temperature"] < 100.0:
        assert status["target"] == 150.0
        assert time.monotonic() < deadline, f"the hotend never passed 100 C: {status}"
        time.sleep(0.2)
    store = http(moonraker + "/server/gcode_store")["gcode_store"]
    assert {"message": "SET_HEATER_TEMPERATURE HEATER=hotend TARGET=150", "type": "command"}.items() <= store[0].items()
