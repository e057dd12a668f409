"""twin-moonraker-agent without its extra: --help works, and a start is one line saying how to install it (the
Quick start's venv has no websocket-client; the module must import there)."""

from __future__ import annotations

import sys

from tools.klipper_host import agent


def test_without_websocket_client_the_agent_says_what_to_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "websocket", None)  # import websocket raises ImportError
    assert agent.main(["--moonraker", "http://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["twin-moonraker-agent: error: no websocket-client for twin-moonraker-agent: "
                   "pip install -e '.[moonraker]'"]
