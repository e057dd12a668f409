"""What the agent asks the printer through Moonraker: a heater's config (its section, gains and limits)
from ``heaters`` and ``configfile.settings``, TWIN_TUNE's parameters checked against them, and klippy's
readiness. A bad parameter is a UserError naming it."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from tools.klipper_host.moonraker_ws import MoonrakerError, MoonrakerSocket
from twin.limits import UserError

POLL_S = 0.2


@dataclass(frozen=True)
class Heater:
    """A heater as printer.cfg states it: the name its commands take, its section, control and gains."""

    name: str  # PID_CALIBRATE's HEATER: extruder, heater_bed, or a heater_generic's own name
    section: str  # printer.cfg's section: extruder, heater_bed, heater_generic <name>
    control: str
    gains: tuple[float, float, float] | None  # (Kp, Ki, Kd) for control: pid
    min_temp_c: float
    max_temp_c: float

    def gains_text(self) -> str:
        if self.gains is None:
            return "(none: control is not pid)"
        return "pid_Kp={:g} pid_Ki={:g} pid_Kd={:g}".format(*self.gains)


@dataclass(frozen=True)
class TuneRequest:
    target_c: float
    from_log: bool


def find_heater(ws: MoonrakerSocket, name: str) -> Heater:
    """The heater named ``name`` as PID_CALIBRATE names it; UserError naming HEATER if there is none."""
    status = ws.call("printer.objects.query", {"objects": {"heaters": ["available_heaters"],
                                                           "configfile": ["settings"]}})["status"]
    full_names = status["heaters"]["available_heaters"]
    names = [full.split()[-1] for full in full_names]
    if not name:
        raise UserError(f"HEATER is missing: name one of {', '.join(names)}")
    if name not in names:
        raise UserError(f"HEATER={name}: no such heater (this printer has: {', '.join(names)})")
    section = full_names[names.index(name)]
    settings = status["configfile"]["settings"][section.lower()]
    gains = (settings["pid_kp"], settings["pid_ki"], settings["pid_kd"]) if settings["control"] == "pid" else None
    return Heater(name, section, settings["control"], gains, settings["min_temp"], settings["max_temp"])


def parse_request(heater: Heater, params: dict) -> TuneRequest:
    """TARGET within the heater's min_temp .. max_temp, FROM_LOG 0 or 1, a PID heater; else a UserError."""
    text = str(params.get("target", "")).strip()
    if not text:
        raise UserError(f"TARGET is missing: a temperature in C below {heater.name}'s max_temp {heater.max_temp_c:g}")
    try:
        target_c = float(text)
    except ValueError:
        raise UserError(f"TARGET={text}: not a temperature in C") from None
    if not math.isfinite(target_c) or not heater.min_temp_c < target_c < heater.max_temp_c:
        raise UserError(f"TARGET={text}: beyond {heater.name}'s limits (min_temp {heater.min_temp_c:g}, "
                        f"max_temp {heater.max_temp_c:g})")
    from_log = str(params.get("from_log", "0")).strip()
    if from_log not in ("0", "1"):
        raise UserError(f"FROM_LOG={from_log}: 0 or 1")
    if heater.gains is None:
        raise UserError(f"HEATER={heater.name}: control is {heater.control}, not pid: the twin tunes PID gains")
    return TuneRequest(target_c, from_log == "1")


def wait_ready(ws: MoonrakerSocket, timeout_s: float, seen: int | None = None) -> None:
    """klippy ready with Moonraker's connection to it set up: at once if printer.info says ready now and
    ``seen`` is None; else after a notify_klippy_ready past the ``seen``-th (or the count at the call)
    and printer.info ready. MoonrakerError with its state on a timeout or a closed socket."""
    deadline = time.monotonic() + timeout_s
    if seen is None:
        seen = ws.klippy_ready_count
        if _info_state(ws, deadline)[0] == "ready":
            return
    ws.wait_klippy_ready(seen, max(0.0, deadline - time.monotonic()))
    _poll_ready(ws, deadline)


def _info_state(ws: MoonrakerSocket, deadline: float) -> tuple[str, str]:
    """klippy's state and message from printer.info, or ('', the error) while Moonraker cannot ask it."""
    try:
        info = ws.call("printer.info", timeout_s=max(1.0, deadline - time.monotonic()))
    except MoonrakerError as exc:
        if ws.closed.is_set():
            raise
        return "", str(exc)
    return info["state"], info.get("state_message", "").strip()


def _poll_ready(ws: MoonrakerSocket, deadline: float) -> None:
    while (state := _info_state(ws, deadline))[0] != "ready":
        if time.monotonic() > deadline:
            raise MoonrakerError(f"klippy is not ready ({': '.join(state)})")
        time.sleep(POLL_S)
