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
def moonraker(klipper, spawn, tmp_path):
    try:
        command = venv_command(MOONRAKER_VENV_ENV)
    except Missing as exc:
        unavailable(str(exc))
    return start_moonraker(command, klipper(), spawn, tmp_path, START_TIMEOUT_S)


def start_moonraker(command, session, spawn, folder, wait_s: float) -> str:
    """Moonraker on a free port in ``folder``, on the session's klippy socket; its base URL once it sees klippy
    ready (a hang guard of ``wait_s``)."""
    port = free_port()
    (folder / "moonraker.conf").write_text(CONFIG.format(port=port, socket=session.api_path))
    with open(folder / "moonraker.out", "w") as out:
        proc = spawn([str(command), "-d", str(folder / "data"), "-c", str(folder / "moonraker.conf"),
                      "-l", str(folder / "moonraker.log")], stdout=out, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + wait_s
    while True:
        try:
            if http(base + "/printer/info")["state"] == "ready":
                return base
        except (OSError, urllib.error.URLError, KeyError):
            pass
        assert proc.poll() is None, (folder / "moonraker.out").read_text()
        assert time.monotonic() < deadline, "Moonraker never saw klippy ready"
        time.sleep(0.2)


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
