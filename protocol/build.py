"""The printer twin-serial and ``twin://`` serve: a scenario, plant presets and an EEPROM file into a
``VirtualPrinter``."""

from __future__ import annotations

from protocol.printer import VirtualPrinter
from protocol.settings import Eeprom
from twin.build import build_twin
from twin.scenario import Scenario, parse_scenario, scenario_for, with_overrides

# A serial printer has no setpoints of its own: the host sets them.
SERIAL_SCENARIO = parse_scenario('name = "serial"\nduration_s = 86400\n', "serial")


def serial_scenario(scenario: str | None, plant: str | None = None, bed_plant: str | None = None) -> Scenario:
    """The scenario a served printer runs: a preset or TOML file (else none: the host sets every
    target), with the hotend and bed plant presets given on the command line in place of its own."""
    chosen = scenario_for(scenario) if scenario else SERIAL_SCENARIO
    # plant names are checked where they are used (make_plant)
    presets: dict[str, dict[str, float | str]] = {heater: {"preset": name} for heater, name in (("hotend", plant), ("bed", bed_plant)) if name}
    return with_overrides(chosen, plant=presets) if presets else chosen


def build_printer(*, firmware: str = "pid", plant: str | None = None, bed_plant: str | None = None,
                  with_bed: bool = True, scenario: str | None = None, settings: str | None = None,
                  ok_after_resend: bool = True, keep_corrupt_settings: bool = False) -> VirtualPrinter:
    """The printer twin-serial and twin:// serve; ValueError names a bad option.

    ``scenario`` (a preset name or TOML file) brings faults, ambient and plant overrides;
    ``settings`` is the file M500 writes (the EEPROM), by default kept in memory only;
    ``keep_corrupt_settings`` refuses one that does not load instead of loading the defaults.
    """
    chosen = serial_scenario(scenario, plant, bed_plant)  # the firmware name is checked by build_controllers
    eeprom = Eeprom.open(settings, keep_corrupt=keep_corrupt_settings) if settings else None
    return VirtualPrinter(lambda: build_twin(chosen, firmware, with_bed=with_bed, engine="fast"),
                          eeprom=eeprom, ok_after_resend=ok_after_resend)
