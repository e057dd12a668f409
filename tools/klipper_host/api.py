"""A client of klippy's API socket (``klippy -a PATH``): JSON requests, each ended by 0x03.

    api = KlippyApi("/tmp/klippy.sock")
    api.wait_ready(timeout_s=60)
    lines = api.gcode("PID_CALIBRATE HEATER=hotend TARGET=200", timeout_s=600)

From a shell: ``python -m tools.klipper_host.api /tmp/klippy.sock "PID_CALIBRATE HEATER=hotend TARGET=200"``
prints the responses, one per line (exit 2 with klippy's message if it refuses the script).

``gcode`` returns the G-code responses the script produced (klippy sends them to the clients
that called ``gcode/subscribe_output``), and raises KlippyError with klippy's own message when
the script fails. Every wait has a timeout.
"""

from __future__ import annotations

import itertools
import json
import select
import socket
import sys
import time
from collections.abc import Callable

from tools.entry import OneLineParser, run_cli
from twin.limits import UserError

TERMINATOR = b"\x03"
OUTPUT_KEY = "heater-twin-output"  # marks the subscription's messages (the response_template)


class KlippyError(RuntimeError):
    """klippy answered a request with an error (its message), or did not answer in time."""


class KlippyApi:
    """One connection to klippy's API socket; ``close()`` (or ``with``) ends it."""

    def __init__(self, path: str, connect_timeout_s: float = 30.0):
        self.path = path
        deadline = time.monotonic() + connect_timeout_s
        while True:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                self._sock.connect(path)
                break
            except OSError as exc:
                self._sock.close()
                if time.monotonic() > deadline:
                    raise KlippyError(f"cannot connect to klippy's API socket {path}: {exc.strerror or exc}") from None
                time.sleep(0.1)
        self._ids = itertools.count(1)
        self._buffer = b""
        self.output: list[str] = []  # every G-code response seen since subscribe_output
        self._subscribed = False

    def __repr__(self) -> str:
        return f"KlippyApi({self.path})"

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> KlippyApi:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def call(self, method: str, params: dict | None = None, timeout_s: float = 30.0) -> dict:
        """One request; its result, or KlippyError with klippy's message."""
        request_id = next(self._ids)
        message = {"id": request_id, "method": method, "params": params or {}}
        deadline = time.monotonic() + timeout_s
        try:
            self._sock.sendall(json.dumps(message).encode() + TERMINATOR)
            while (reply := self._next_message(deadline, f"{method} {params or ''}")).get("id") != request_id:
                pass
        except OSError as exc:  # klippy restarting or gone
            raise KlippyError(f"lost klippy's API socket during {method}: {exc.strerror or exc}") from None
        if "error" in reply:
            raise KlippyError(reply["error"].get("message", str(reply["error"])))
        return reply.get("result", {})

    def info(self) -> dict:
        return self.call("info")

    def wait_ready(self, timeout_s: float = 60.0, progress: Callable[[], object] = lambda: None) -> dict:
        """Poll ``info`` until klippy's state is ready; KlippyError with its state message if it
        reaches shutdown or error, or after ``timeout_s`` in which ``progress()`` did not change
        (a sign of life, such as klippy.log's size; by default the timeout counts from the call)."""
        seen, deadline = progress(), time.monotonic() + timeout_s
        while True:
            info = self.info()
            if info.get("state") == "ready":
                return info
            if (now := progress()) != seen:
                seen, deadline = now, time.monotonic() + timeout_s
            if info.get("state") in ("shutdown", "error") or time.monotonic() > deadline:
                raise KlippyError(f"klippy is {info.get('state')}: {info.get('state_message', '').strip()}")
            time.sleep(0.1)

    def gcode(self, script: str, timeout_s: float = 60.0) -> list[str]:
        """Run a G-code script; the responses it printed (the lines of each, "// " kept)."""
        if not self._subscribed:
            self.call("gcode/subscribe_output", {"response_template": {"key": OUTPUT_KEY}})
            self._subscribed = True
        first = len(self.output)
        self.call("gcode/script", {"script": script}, timeout_s)
        return self.output[first:]

    def query(self, *objects: str) -> dict:
        """objects/query of the named printer objects, all their fields."""
        return self.call("objects/query", {"objects": dict.fromkeys(objects)})["status"]

    def print_time(self) -> float:
        """klippy's estimated print time: the MCU's clock in seconds, as klippy's clock sync sees it."""
        return self.query("toolhead")["toolhead"]["estimated_print_time"]

    def wait_print_time(self, until_s: float, timeout_s: float) -> None:
        """Until klippy's print time reaches ``until_s`` (KlippyError after ``timeout_s`` of wall time: a hang
        guard, the wait itself is the MCU clock's)."""
        deadline = time.monotonic() + timeout_s
        while self.print_time() < until_s:
            if time.monotonic() > deadline:
                raise KlippyError(f"klippy's print time never reached {until_s:.1f} s")
            time.sleep(0.05)

    def _next_message(self, deadline: float, what: str) -> dict:
        while TERMINATOR not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._sock], [], [], left)[0]:
                raise KlippyError(f"no answer from klippy to {what}")
            data = self._sock.recv(65536)
            if not data:
                raise KlippyError(f"klippy closed the API socket during {what}")
            self._buffer += data
        raw, _, self._buffer = self._buffer.partition(TERMINATOR)
        message = json.loads(raw)
        if message.get("key") == OUTPUT_KEY:
            self.output.extend(message["params"]["response"].split("\n"))
        return message


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m tools.klipper_host.api", description="Run a G-code script through "
                           "klippy's API socket and print its responses.")
    parser.add_argument("socket", help="klippy's API socket (klippy -a PATH)")
    parser.add_argument("script", help='G-code, e.g. "PID_CALIBRATE HEATER=hotend TARGET=200"')
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds to wait (default: %(default)s)")

    def run(args) -> int:
        with KlippyApi(args.socket) as api:
            api.wait_ready(args.timeout)
            for line in api.gcode(args.script, args.timeout):
                print(line)
        return 0

    return run_cli(parser, run, argv, errors=(KlippyError, UserError))


if __name__ == "__main__":
    sys.exit(main())
