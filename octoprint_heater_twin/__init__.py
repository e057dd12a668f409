"""OctoPrint plugin: tune the connected printer's PID with heater-twin.

A tab runs the firmware's own autotune (M303) and streams it, or takes a pasted capture; twin-tune
tunes the capture in a process of its own; the tab shows the answer ("keep your gains" or new gains,
why, the proof, a plot), and Apply sends M301/M304 and M500 and reads them back with M503. Registered
through OctoPrint's ``octoprint.plugin`` entry point (pyproject.toml); docs/octoprint.md.
"""

from __future__ import annotations

import math
from pathlib import Path

import flask
import octoprint.plugin
from octoprint.access.permissions import Permissions
from octoprint.events import Events

from octoprint_heater_twin.console import HEATERS, Gains
from octoprint_heater_twin.session import Session

TAG = "plugin:heater_twin"  # on the commands the plugin queues: the sending hook tells them from the user's
DEFAULTS = {"heater": "extruder", "extruder_target_c": 210, "bed_target_c": 60, "cycles": 8,
            "autotune_timeout_min": 30}


class OctoPrintPrinter:
    """The session's printer: OctoPrint's, refusing while not connected or busy."""

    def __init__(self, printer):
        self.printer = printer

    def refusal(self) -> str | None:
        if not self.printer.is_operational():
            return f"The printer is not connected ({self.printer.get_state_string()}): connect it first"
        if not self.printer.is_ready():
            return f"The printer is busy ({self.printer.get_state_string()}): it must be idle, not printing"
        return None

    def send(self, commands: list[str]) -> None:
        self.printer.commands(commands, tags={TAG})


class HeaterTwinPlugin(octoprint.plugin.SettingsPlugin, octoprint.plugin.TemplatePlugin,
                       octoprint.plugin.AssetPlugin, octoprint.plugin.SimpleApiPlugin,
                       octoprint.plugin.EventHandlerPlugin):
    session: Session

    def initialize(self) -> None:
        runs_dir = Path(self.get_plugin_data_folder()) / "runs"
        self.session = Session(runs_dir, OctoPrintPrinter(self._printer), self._publish)

    def _publish(self, message: dict) -> None:
        self._plugin_manager.send_plugin_message(self._identifier, message)

    # -- settings, templates, assets --------------------------------------------------------------------
    def get_settings_defaults(self) -> dict:
        return dict(DEFAULTS)

    def is_template_autoescaped(self) -> bool:
        return True

    def get_template_configs(self) -> list[dict]:
        return [{"type": "tab", "name": "Heater tuning", "custom_bindings": True},
                {"type": "settings", "name": "Heater tuning", "custom_bindings": False}]

    def get_template_vars(self) -> dict:
        return {"heaters": list(HEATERS)}

    def get_assets(self) -> dict:
        return {"js": ["js/heater_twin.js"], "css": ["css/heater_twin.css"]}

    # -- the tab's API: /api/plugin/heater_twin ------------------------------------------------------------
    def is_api_protected(self) -> bool:
        return True

    def get_api_commands(self) -> dict:
        return {"start": ["heater", "target_c", "cycles"], "paste": ["heater", "text"], "check": ["kp", "ki", "kd"],
                "apply": []}

    def on_api_command(self, command: str, data: dict):
        if not Permissions.CONTROL.can():
            flask.abort(403)
        try:
            refused = self._request(command, data)
        except (TypeError, ValueError) as exc:
            return flask.make_response(flask.jsonify(error=str(exc)), 400)
        if refused:
            return flask.make_response(flask.jsonify(error=refused), 409)
        return flask.jsonify(self.session.state())

    def _request(self, command: str, data: dict) -> str | None:
        if command == "start":
            timeout_s = 60.0 * self._settings.get_float(["autotune_timeout_min"])
            return self.session.start(str(data["heater"]), _number(data, "target_c"), _integer(data, "cycles"),
                                      timeout_s)
        if command == "paste":
            return self.session.paste(str(data["text"]), str(data["heater"]))
        if command == "check":
            return self.session.check(_gains(data))
        return self.session.apply(_gains(data["gains"]) if data.get("gains") else None)

    def on_api_get(self, request):
        if not Permissions.STATUS.can():
            flask.abort(403)
        if "plot" in request.args:
            path = self.session.plot(compact=request.args.get("figure") == "tab")
            if path is None:
                flask.abort(404)
            return flask.send_file(path, mimetype="image/png", max_age=0)
        return flask.jsonify(self.session.state())

    # -- the printer's lines and state ---------------------------------------------------------------------
    def on_line_received(self, comm, line: str, *args, **kwargs) -> str:
        self.session.on_received(line)
        return line

    def on_gcode_sending(self, comm, phase, cmd: str, cmd_type, gcode, *args, tags=None, **kwargs) -> None:
        """Just before one of our commands is written (not after: twin-serial may have answered by then)."""
        if tags and TAG in tags:
            self.session.on_sending(cmd)

    def on_event(self, event: str, payload) -> None:
        if event == Events.DISCONNECTED:
            self.session.on_printer_lost("disconnected")
        elif event == Events.ERROR:
            self.session.on_printer_lost((payload or {}).get("error", "error"))


def _number(data: dict, field: str) -> float:
    """A number from the request, or ValueError naming the field."""
    try:
        value = float(data[field])
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"{field} {data[field]!r}: not a number")
    return value


def _gains(data: dict) -> Gains:
    """The gains the user edited, {"kp": .., "ki": .., "kd": ..}, or ValueError naming the field."""
    fields = ("kp", "ki", "kd")
    if not isinstance(data, dict) or any(field not in data for field in fields):
        raise ValueError(f"gains {data!r}: give kp, ki and kd")
    return Gains(*(_number(data, field) for field in fields))


def _integer(data: dict, field: str) -> int:
    value = _number(data, field)
    if not value.is_integer():
        raise ValueError(f"{field} {data[field]!r}: not a whole number")
    return int(value)


__plugin_name__ = "Heater tuning (heater-twin)"
__plugin_description__ = "Autotune the printer, let heater-twin prove better PID gains, apply and read them back"
__plugin_license__ = "GPL-3.0-or-later"
__plugin_pythoncompat__ = ">=3.11,<4"
__plugin_implementation__ = HeaterTwinPlugin()
__plugin_hooks__ = {
    "octoprint.comm.protocol.gcode.received": __plugin_implementation__.on_line_received,
    "octoprint.comm.protocol.gcode.sending": __plugin_implementation__.on_gcode_sending,
}
