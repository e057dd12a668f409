"""TWIN_TUNE and TWIN_APPLY on the user's printer.cfg path: twin-klipper-mcu --printer-cfg serves the board of
Klipper's own example config for the Creality Ender 3 V2 (only [mcu]'s serial changed, as
test_printer_cfg.py does, and tools/klipper_host/twin_tune.cfg included), the registry's klippy runs it with
its steppers, [extruder] and PID-controlled [heater_bed], and Moonraker 0.11 and twin-moonraker-agent run on
top. The console is driven and read as in test_twin_tune.py (its Printer and helpers): every wait is on a
console line, with a hang guard of minutes, and the klipper fixture runs a session that missed the MCU's
schedule again slower."""

from __future__ import annotations

import time

import pytest

from tests.klipper_mcu.test_printer_cfg import example_config
from tests.klipper_mcu.test_twin_tune import (
    Printer,
    answer_gains,
    apply_holds,
    comparable,
    doc_transcript,
    errors,
    moonraker_command,
    start_printer,
    transcript,
)

pytestmark = pytest.mark.slow

CONFIG = "printer-creality-ender3-v2-2020.cfg"
SECTION = "extruder"
# the example's [extruder] gains and limits, as its file states them
EXAMPLE_GAINS = {"control": "pid", "pid_kp": 21.527, "pid_ki": 1.063, "pid_kd": 108.982}
EXTRUDER_PID = ("control: pid\n# tuned for stock hardware with 200 degree Celsius target\n"
                "pid_Kp: 21.527\npid_Ki: 1.063\npid_Kd: 108.982\n")
# Klipper's SAVE_CONFIG header (klippy/configfile.py's AUTOSAVE_HEADER), as SAVE_CONFIG writes it
SAVE_CONFIG_HEADER = ("#*# <---------------------- SAVE_CONFIG ---------------------->\n"
                      "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n#*#\n")


@pytest.fixture
def ender(klipper) -> Printer:
    command, path = moonraker_command(), example_config(CONFIG)
    return klipper.fixture("the Ender 3 V2 printer fixture",
                           lambda: start_printer(klipper, command, "--printer-cfg", str(path), section=SECTION))


def saved_by_save_config(original: str, gains: dict[str, str]) -> str:
    """What Klipper's SAVE_CONFIG writes after PID_CALIBRATE HEATER=extruder found ``gains`` (as printed, 3
    decimals): [extruder]'s control and gains commented out where the file sets them (the comment between
    them as it was), the file's end stripped, then the block with the section's four options."""
    assert original.count(EXTRUDER_PID) == 1, "the example's [extruder] is not as this test knows it"
    commented = "".join(line if line.startswith("#") else "#" + line
                        for line in EXTRUDER_PID.splitlines(keepends=True))
    block = [f"[{SECTION}]", "control = pid", *(f"{key.lower()} = {gains[key]}" for key in ("pid_Kp", "pid_Ki",
                                                                                           "pid_Kd"))]
    return (original.replace(EXTRUDER_PID, commented).rstrip() + "\n\n" + SAVE_CONFIG_HEADER
            + "".join(f"#*# {line}\n" for line in block))


def as_extruder(lines: list[str]) -> list[str]:
    """docs/klipper.md's transcript (the heater-only board's hotend) as it reads for the example's [extruder]."""
    return [line.replace("heater_generic hotend", SECTION).replace("hotend", SECTION) for line in lines]


def test_twin_tune_then_twin_apply_on_an_example_printer_cfg(ender):
    original = ender.session.config_path.read_text()
    assert ender.gains() == EXAMPLE_GAINS
    first = ender.send("TWIN_TUNE HEATER=extruder TARGET=210")
    lines = ender.wait_line("TWIN_TUNE: verdict:", first)
    assert errors(lines) == [], lines
    assert "// TWIN_TUNE: PID_CALIBRATE HEATER=extruder TARGET=210 (the temperatures follow)" in lines
    assert any(line.startswith("B:") and " T0:" in line for line in lines)  # PID_CALIBRATE heats the extruder
    assert any(line.startswith("// PID parameters: pid_Kp=") for line in lines)  # PID_CALIBRATE's own reply
    assert ("// TWIN_TUNE: the twin tunes extruder at 210 C from klippy.log on Klipper's loop, against your gains "
            "pid_Kp=21.527 pid_Ki=1.063 pid_Kd=108.982") in lines  # the example's own gains are the ones to beat
    assert "// TWIN_TUNE: verdict: new gains" in lines
    lines = ender.wait_line("TWIN_TUNE: answer:", first)
    answer = answer_gains(lines)
    assert ender.gains() == EXAMPLE_GAINS and ender.session.config_path.read_text() == original  # nothing applied

    apply_holds(ender, answer)
    assert ender.session.config_path.read_text() == saved_by_save_config(original, answer)
    backups = list(ender.session.config_path.parent.glob("printer-*.cfg"))
    assert [b.read_text() for b in backups] == [original]
    lines = transcript(ender.console())
    (ender.workdir / "transcript.txt").write_text("\n".join(lines) + "\n")
    assert comparable(lines) == comparable(as_extruder(doc_transcript())), f"this run's console: {lines}"


@pytest.mark.parametrize("script, message", [
    ("TWIN_TUNE HEATER=extruder TARGET=400", "!! TWIN_TUNE: TARGET=400: beyond extruder's limits (min_temp 0, "
                                             "max_temp 250)"),
    ("TWIN_TUNE HEATER=hotend TARGET=210", "!! TWIN_TUNE: HEATER=hotend: no such heater (this printer has: "
                                           "heater_bed, extruder)"),  # klippy's order
])
def test_bad_input_on_an_example_printer_cfg_is_one_line(ender, script, message):
    original, before = ender.session.config_path.read_text(), ender.gains()
    first = ender.send(script)
    lines = ender.wait_line("!!", first)
    time.sleep(1.0)  # a second line, if the agent printed one, would be in the store by now
    assert [line for line in ender.console()[first:] if line.startswith(("!!", "// TWIN"))] == [message], lines
    assert ender.session.config_path.read_text() == original and ender.gains() == before == EXAMPLE_GAINS
