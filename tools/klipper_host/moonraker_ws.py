"""A JSON-RPC client of Moonraker's websocket (``ws://HOST:PORT/websocket``) that can act as an agent.

    with MoonrakerSocket("ws://127.0.0.1:7125/websocket") as ws:
        ws.call("server.connection.identify", {"client_name": "x", "version": "1", "type": "agent", "url": ""})
        ws.call("connection.register_remote_method", {"method_name": "twin_tune"})
        method, params = ws.methods.get(timeout=60)   # klippy's action_call_remote_method("twin_tune", ...)

A reader thread sorts what arrives: answers to ``call`` (by id), Moonraker's calls of a registered
remote method (a message with a method and no id, put on ``methods``), and notify_klippy_ready,
counted in ``klippy_ready_count`` (Moonraker sends it once klippy is ready and Moonraker has
subscribed to its G-code output and registered the agents' methods again; printer.info says ready
before that, and a RESPOND then never reaches the console); other notifications are dropped.
Every wait has a timeout; a closed socket fails the calls waiting on it with MoonrakerError.
"""

from __future__ import annotations

import itertools
import json
import queue
import threading
from types import ModuleType

NOTIFICATION_PREFIX = "notify_"  # Moonraker's broadcasts (status updates, gcode responses, ...)
KLIPPY_READY = "notify_klippy_ready"


class MoonrakerError(RuntimeError):
    """Moonraker answered a call with an error (its message), did not answer in time, or the socket closed."""


def _websocket() -> ModuleType:
    """websocket-client (the 'moonraker' extra), imported when a socket is made: --help and the tests of the
    rest run without it."""
    try:
        import websocket
    except ImportError:
        raise MoonrakerError("no websocket-client for twin-moonraker-agent: pip install -e '.[moonraker]'") from None
    return websocket


class MoonrakerSocket:
    """One websocket connection to Moonraker; ``close()`` (or ``with``) ends it and its reader thread."""

    def __init__(self, url: str, connect_timeout_s: float = 30.0):
        self.url = url
        websocket = self._websocket = _websocket()
        try:
            self._ws = websocket.create_connection(url, timeout=connect_timeout_s)
        except (OSError, self._websocket.WebSocketException) as exc:
            raise MoonrakerError(f"cannot connect to Moonraker at {url}: {exc}") from None
        self._ws.settimeout(None)  # the reader blocks until a message or close()
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._pending: dict[int, queue.Queue] = {}
        self.methods: queue.Queue = queue.Queue()  # (method, params); (None, reason) once the socket closed
        self.closed = threading.Event()
        self.klippy_ready_count = 0
        self.klippy_ready = threading.Condition()
        self._reader = threading.Thread(target=self._read, name="moonraker-ws", daemon=True)
        self._reader.start()

    def __repr__(self) -> str:
        return f"MoonrakerSocket({self.url})"

    def __enter__(self) -> MoonrakerSocket:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self) -> None:
        self._ws.close()
        self._reader.join(timeout=5.0)

    def call(self, method: str, params: dict | None = None, timeout_s: float = 60.0):
        """One request; its result, or MoonrakerError with Moonraker's message."""
        request_id = next(self._ids)
        answer: queue.Queue = queue.Queue(maxsize=1)
        with self._lock:
            if self.closed.is_set():
                raise MoonrakerError(f"Moonraker's websocket is closed (during {method})")
            self._pending[request_id] = answer
        message = {"jsonrpc": "2.0", "method": method, "params": params or {}, "id": request_id}
        try:
            self._ws.send(json.dumps(message))
            reply = answer.get(timeout=timeout_s)
        except queue.Empty:
            raise MoonrakerError(f"no answer from Moonraker to {method} within {timeout_s:g} s") from None
        except (OSError, self._websocket.WebSocketException) as exc:
            raise MoonrakerError(f"lost Moonraker's websocket during {method}: {exc}") from None
        finally:
            with self._lock:
                self._pending.pop(request_id, None)
        if "error" in reply:
            error = reply["error"]
            raise MoonrakerError(error.get("message", str(error)) if isinstance(error, dict) else str(error))
        return reply.get("result")

    def wait_klippy_ready(self, seen: int, timeout_s: float) -> None:
        """Wait for a notify_klippy_ready after the ``seen``-th; MoonrakerError on a timeout or a closed socket."""
        with self.klippy_ready:
            if not self.klippy_ready.wait_for(lambda: self.klippy_ready_count > seen or self.closed.is_set(),
                                              timeout_s):
                raise MoonrakerError(f"Moonraker never said klippy was ready again within {timeout_s:g} s")
        if self.klippy_ready_count <= seen:
            raise MoonrakerError("Moonraker's websocket closed while klippy was restarting")

    def _read(self) -> None:
        reason = "closed"
        try:
            while True:
                text = self._ws.recv()
                if not text:
                    break
                self._dispatch(json.loads(text))
        except (OSError, self._websocket.WebSocketException, ValueError) as exc:
            reason = str(exc) or type(exc).__name__
        with self._lock:
            self.closed.set()
            waiting = list(self._pending.values())
        with self.klippy_ready:
            self.klippy_ready.notify_all()
        for answer in waiting:
            answer.put({"error": {"message": f"Moonraker's websocket closed: {reason}"}})
        self.methods.put((None, reason))

    def _dispatch(self, message: dict) -> None:
        if "id" in message and "method" not in message:
            with self._lock:
                answer = self._pending.get(message["id"])
            if answer is not None:
                answer.put(message)
        elif message.get("method") == KLIPPY_READY:
            with self.klippy_ready:
                self.klippy_ready_count += 1
                self.klippy_ready.notify_all()
        elif "method" in message and not message["method"].startswith(NOTIFICATION_PREFIX):
            self.methods.put((message["method"], message.get("params") or {}))
