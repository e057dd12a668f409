"""The plugin as OctoPrint finds it: registered under the ``octoprint.plugin`` entry point, its templates and
static files shipped as package data, and light in OctoPrint's process (the tune runs in twin-tune's)."""

from __future__ import annotations

import ast
import importlib
import tomllib
from importlib.metadata import entry_points
from pathlib import Path

from tests.helpers.octoprint_server import require_octoprint

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "octoprint_heater_twin"
PROJECT_PACKAGES = ("firmware_port", "twin", "protocol", "tools")


def test_the_entry_point_names_the_plugin():
    require_octoprint()
    (point,) = [p for p in entry_points(group="octoprint.plugin") if p.name == "heater_twin"]
    module = importlib.import_module(point.value)
    assert module.__plugin_implementation__.get_api_commands() == {
        "start": ["heater", "target_c", "cycles"], "paste": ["heater", "text"], "check": ["kp", "ki", "kd"],
        "apply": []}
    assert set(module.__plugin_hooks__) == {"octoprint.comm.protocol.gcode.received",
                                            "octoprint.comm.protocol.gcode.sending"}


def test_every_template_and_static_file_is_package_data():
    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    shipped = {path for pattern in globs["octoprint_heater_twin"] for path in PLUGIN.glob(pattern)}
    files = {path for folder in ("templates", "static") for path in (PLUGIN / folder).rglob("*") if path.is_file()}
    assert files and files == shipped


def test_the_plugin_imports_none_of_the_project():
    """numpy, scipy and numba stay out of OctoPrint's process: the plugin reaches heater-twin through twin-tune."""
    imported = set()
    for path in PLUGIN.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module:
                imported.add(node.module.split(".")[0])
    assert imported & set(PROJECT_PACKAGES) == set()
