"""Scenarios: what happens to the printer, and when, for one run of the twin.

A scenario is a TOML file (layout in docs/scenarios.md) or one of the built-in PRESETS: the run's
duration, the ambient and initial temperatures, plant parameter overrides, and timed events
(setpoints, part fan, extrusion flow, ambient changes, faults). Every problem in a file is one
ScenarioError naming the file and the field, never a traceback.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import re
import sys
import textwrap
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, cast

from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX
from twin.limits import AMBIENT_RANGE_C, DURATION_MAX_S, INITIAL_RANGE_C, TARGET_RANGE_C, check_regular_file

HEATERS = ("hotend", "bed")
FAULT_KINDS = (
    "thermistor_open",  # sensor wire broken: the ADC reads full scale, the coldest table entry
    "thermistor_short",  # sensor shorted: the ADC reads 0, the hottest table entry
    "thermistor_detached",  # sensor out of its bore: it reads a small node coupled to ambient
    "heater_disconnected",  # cartridge out or wire broken: no heater power whatever the pin says
    "heater_stuck_on",  # MOSFET failed short: full heater power whatever the pin says
    "fan_failure",  # the part fan stops whatever its PWM says (no heater)
)
DEFAULT_AMBIENT_C = 25.0
# Filament feed: at most Marlin's DEFAULT_MAX_FEEDRATE for E (Configuration.h), the fastest its
# planner ever feeds (60 mm^3/s of 1.75 mm filament, beyond any hotend's melt rate); far beyond
# it the lumped model's loss term dwarfs the rest and its discretisation loses all precision.
FLOW_MAX_MM_S = 25.0
OVERRIDES_SOURCE = "overrides"  # the "file" named in errors from with_overrides

# TOML array of tables -> its fields; each entry becomes one Event (see _read_event).
_EVENT_TABLES = {
    "pid": ("at_s", "heater", "kp", "ki", "kd"),
    "setpoint": ("at_s", "heater", "target_c"),
    "fan": ("at_s", "speed"),
    "flow": ("at_s", "mm_s"),
    "ambient": ("at_s", "temp_c"),
    "fault": ("at_s", "kind", "heater"),
}
_TOP_FIELDS = ("name", "description", "duration_s", "ambient_c", "seed", "initial_c", "plant",
               *_EVENT_TABLES)
_REQUIRED = object()  # default of a field that must be present


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Event:
    """One change at `at_s` seconds: kind "gains", "target", "fan", "flow", "ambient" or "fault".

    value: (kp, ki, kd) in M301/M304 units for "gains", target degC (int) for "target", part-fan fraction 0..1 for "fan", filament feed mm/s
    for "flow" (heater "hotend"), degC for "ambient", a FAULT_KINDS name for "fault".
    heater: "hotend"/"bed", or None for "fan", "ambient" and the "fan_failure" fault.
    """

    at_s: float
    kind: str
    heater: str | None
    value: float | str | tuple[float, float, float] | None


@dataclass(frozen=True)
class Scenario:
    """One run: events sorted by time (ties: pid, setpoint, fan, flow, ambient, fault, then file order)."""

    name: str
    duration_s: float
    ambient_c: float
    initial_c: dict[str, float]  # every heater; a heater not given in the file starts at ambient
    events: tuple[Event, ...]
    plant: dict[str, dict[str, float | str]]  # per heater, passed to the plant factory as is
    seed: int | None
    description: str


def _show(value: Any) -> str:
    """A TOML value as a message quotes it: shortened, tables and arrays named."""
    if isinstance(value, str):
        return _toml_string(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        text = repr(value)
        return text if len(text) <= 40 else text[:37] + "..."
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return f"a {type(value).__name__}"  # TOML dates and times


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _error(source: str, where: str, problem: str) -> ScenarioError:
    return ScenarioError(f"{source}: {where}: {problem}" if where else f"{source}: {problem}")


def _suggest(word: str, choices: tuple[str, ...] | list[str]) -> str:
    """' (did you mean "x"?)' for a near miss, else the list of choices."""
    close = difflib.get_close_matches(word, choices, n=1)
    if close:
        return f' (did you mean "{close[0]}"?)'
    return "; expected one of " + ", ".join(f'"{choice}"' for choice in choices)


class _Table:
    """One TOML table of a scenario: typed field reads, each error naming the file and the field."""

    def __init__(self, data: dict[str, Any], source: str, path: str, fields: tuple[str, ...] | None):
        self.data, self.source, self.path = data, source, path
        if fields is not None:
            for key in data:
                if key not in fields:
                    self.fail(None, f"unknown field {_show(key)}" + _suggest(key, fields))

    def where(self, key: str | None) -> str:
        """The field's path as TOML writes it: plant.hotend.power_w, setpoint[2].target_c."""
        parts = [self.path] if self.path else []
        return ".".join(parts if key is None else [*parts, _toml_key(key)])

    def fail(self, key: str | None, problem: str) -> NoReturn:
        raise _error(self.source, self.where(key), problem)

    def get(self, key: str, default: Any = _REQUIRED) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            self.fail(key, "missing required field")
        return default

    def number(self, key: str, lo: float = -math.inf, hi: float = math.inf,
               default: Any = _REQUIRED) -> float:
        if key not in self.data and default is not _REQUIRED:
            return default
        value = self.get(key)
        if not _is_number(value):
            self.fail(key, f"expected a number, got {_show(value)}")
        if isinstance(value, float) and math.isnan(value) or abs(value) > sys.float_info.max:
            self.fail(key, f"must be a finite number, got {_show(value)}")  # inf, or an int too big
        if not lo <= value <= hi:
            bounds = f">= {lo:g}" if hi == math.inf else f"in {lo:g}..{hi:g}"
            self.fail(key, f"must be {bounds}, got {_show(value)}")
        return float(value)

    def whole(self, key: str, lo: int, hi: int) -> int:
        value = self.number(key, lo, hi)
        if not value.is_integer():
            self.fail(key, f"must be a whole number, got {_show(self.data[key])}")
        return int(value)

    def string(self, key: str, default: Any = _REQUIRED) -> str:
        value = self.get(key, default)
        if not isinstance(value, str):
            self.fail(key, f"expected a string, got {_show(value)}")
        return value

    def choice(self, key: str, choices: tuple[str, ...], what: str, default: Any = _REQUIRED) -> str:
        value = self.string(key, default)
        if value not in choices:
            self.fail(key, f"unknown {what} {_show(value)}" + _suggest(value, choices))
        return value

    def scalar(self, key: str) -> float | str:
        """A plant parameter: a string, or a finite number as float."""
        value = self.data[key]
        if isinstance(value, str):
            return value
        if not _is_number(value):
            self.fail(key, f"expected a number or a string, got {_show(value)}")
        return self.number(key)

    def table(self, key: str, fields: tuple[str, ...] | None) -> _Table:
        """A sub-table; an absent one reads as empty."""
        value = self.get(key, {})
        if not isinstance(value, dict):
            self.fail(key, f"expected a table ([{self.where(key)}]), got {_show(value)}")
        return _Table(value, self.source, self.where(key), fields)

    def array(self, key: str, fields: tuple[str, ...]) -> list[_Table]:
        """An array of tables ([[key]]); an absent one reads as empty."""
        value = self.get(key, [])
        if not isinstance(value, list):
            self.fail(key, f"expected an array of tables ([[{self.where(key)}]]), got {_show(value)}")
        entries = []
        for i, entry in enumerate(value):
            where = f"{self.where(key)}[{i}]"
            if not isinstance(entry, dict):
                raise _error(self.source, where, f"expected a table, got {_show(entry)}")
            entries.append(_Table(entry, self.source, where, fields))
        return entries


def _read_duration(top: _Table) -> float:
    duration_s = top.number("duration_s")
    if duration_s <= 0.0:
        top.fail("duration_s", f"must be > 0, got {_show(top.data['duration_s'])}")
    if duration_s > DURATION_MAX_S:
        top.fail("duration_s", f"must be at most {DURATION_MAX_S:g} s (49.7 days, when Marlin's 32-bit millis() "
                 f"wraps), got {_show(top.data['duration_s'])}")
    return duration_s


def _read_initial(top: _Table) -> dict[str, float]:
    initial = top.table("initial_c", HEATERS)
    return {heater: initial.number(heater, *INITIAL_RANGE_C) for heater in initial.data}


def _read_plant(top: _Table) -> dict[str, dict[str, float | str]]:
    plant = top.table("plant", HEATERS)
    overrides = {}
    for heater in plant.data:
        params = plant.table(heater, None)
        overrides[heater] = {key: params.scalar(key) for key in params.data}
    return overrides


def _read_seed(top: _Table) -> int | None:
    seed = top.get("seed", None)
    if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool) or seed < 0):
        top.fail("seed", f"expected a non-negative integer, got {_show(seed)}")
    return seed


def _read_gains(entry: _Table) -> tuple[float, float, float]:
    """M301/M304 gains within the range the firmware's fixed-point PID supports."""
    return (entry.number("kp", 0.0, KP_MAX), entry.number("ki", 0.0, KI_MAX), entry.number("kd", 0.0, KD_MAX))


def _read_event(table: str, entry: _Table, duration_s: float) -> Event:
    at_s = entry.number("at_s", 0.0)
    if at_s > duration_s:
        entry.fail("at_s", f"{at_s:g} s is after the end of the run (duration_s = {duration_s:g})")
    match table:
        case "pid":
            return Event(at_s, "gains", entry.choice("heater", HEATERS, "heater"), _read_gains(entry))
        case "setpoint":
            return Event(at_s, "target", entry.choice("heater", HEATERS, "heater"),
                         entry.whole("target_c", *TARGET_RANGE_C))
        case "fan":
            return Event(at_s, "fan", None, entry.number("speed", 0.0, 1.0))
        case "flow":
            return Event(at_s, "flow", "hotend", entry.number("mm_s", 0.0, FLOW_MAX_MM_S))
        case "ambient":
            return Event(at_s, "ambient", None, entry.number("temp_c", *AMBIENT_RANGE_C))
    kind = entry.choice("kind", FAULT_KINDS, "fault")
    if kind == "fan_failure":
        if "heater" in entry.data:
            entry.fail("heater", "fan_failure has no heater (it is the part fan); remove this field")
        return Event(at_s, "fault", None, kind)
    return Event(at_s, "fault", entry.choice("heater", HEATERS, "heater"), kind)


def parse_scenario(text: str, source: str) -> Scenario:
    """The scenario in TOML `text`; `source` names the file in errors and gives the default name."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{source}: TOML syntax error: {error}") from None
    except RecursionError:
        raise ScenarioError(f"{source}: TOML syntax error: arrays or tables nested too deeply") from None
    top = _Table(data, source, "", _TOP_FIELDS)
    duration_s = _read_duration(top)
    ambient_c = top.number("ambient_c", *AMBIENT_RANGE_C, default=DEFAULT_AMBIENT_C)
    events = [_read_event(table, entry, duration_s)
              for table, fields in _EVENT_TABLES.items() for entry in top.array(table, fields)]
    return Scenario(
        name=top.string("name", Path(source).stem),
        duration_s=duration_s,
        ambient_c=ambient_c,
        initial_c=dict.fromkeys(HEATERS, ambient_c) | _read_initial(top),
        events=tuple(sorted(events, key=lambda event: event.at_s)),
        plant=_read_plant(top),
        seed=_read_seed(top),
        description=top.string("description", ""),
    )


def load_scenario(path: str | Path) -> Scenario:
    """The scenario in the TOML file at `path`."""
    try:
        check_regular_file(path)
        text = Path(path).read_text(encoding="utf-8")
    except OSError as error:
        raise ScenarioError(f"{path}: cannot read: {error.strerror or error}") from None
    except UnicodeDecodeError as error:
        raise ScenarioError(f"{path}: not UTF-8 text (byte {error.start})") from None
    except ValueError as error:  # not a regular file
        raise ScenarioError(f"{path}: {error}") from None
    return parse_scenario(text, str(path))


def _toml_string(text: str) -> str:
    """A TOML basic string: JSON's escapes are TOML's, except that TOML also forbids a raw DEL."""
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_string(key)


def _toml_value(value: float | str) -> str:
    return _toml_string(value) if isinstance(value, str) else repr(value)


def _event_fields(event: Event) -> tuple[str, dict[str, Any]]:
    """The array of tables an event is written to, and its fields."""
    match event.kind:
        case "gains":
            kp, ki, kd = cast(tuple[float, float, float], event.value)
            return "pid", {"heater": event.heater, "kp": kp, "ki": ki, "kd": kd}
        case "target":
            return "setpoint", {"heater": event.heater, "target_c": event.value}
        case "fan":
            return "fan", {"speed": event.value}
        case "flow":
            return "flow", {"mm_s": event.value}
        case "ambient":
            return "ambient", {"temp_c": event.value}
    heater = {} if event.heater is None else {"heater": event.heater}
    return "fault", {"kind": event.value, **heater}


def dump_scenario(scenario: Scenario) -> str:
    """TOML text that parse_scenario reads back as an equal Scenario (e.g. a preset to edit)."""
    lines = [f"name = {_toml_string(scenario.name)}",
             f"description = {_toml_string(scenario.description)}",
             f"duration_s = {scenario.duration_s!r}",
             f"ambient_c = {scenario.ambient_c!r}"]
    if scenario.seed is not None:
        lines.append(f"seed = {scenario.seed}")
    sections: list[tuple[str, dict[str, Any]]] = [("initial_c", dict(scenario.initial_c))]
    sections += [(f"plant.{heater}", dict(params)) for heater, params in scenario.plant.items()]
    for header, values in sections:
        lines += ["", f"[{header}]"] + [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in values.items()]
    for table in _EVENT_TABLES:  # the tie order of parse_scenario, so the round trip is exact
        for event in scenario.events:
            name, fields = _event_fields(event)
            if name == table:
                lines += ["", f"[[{table}]]", f"at_s = {event.at_s!r}"]
                lines += [f"{k} = {_toml_value(v)}" for k, v in fields.items()]
    return "\n".join(lines) + "\n"


def with_overrides(scenario: Scenario, *, duration_s: float | None = None,
                   ambient_c: float | None = None, initial_c: dict[str, float] | None = None,
                   targets: dict[str, int] | None = None, seed: int | None = None,
                   plant: dict[str, dict[str, float | str]] | None = None,
                   gains: dict[str, dict[str, float]] | None = None) -> Scenario:
    """The scenario with command-line values in place of the file's, checked like the file's.

    duration_s drops the events after it; ambient_c also moves the heaters that started at the
    old ambient; targets[heater] replaces that heater's first setpoint, or adds one at 0 s;
    plant parameters are merged into the file's, heater by heater; gains[heater] ({"kp", "ki",
    "kd"}) replace that heater's gains at 0 s (the firmware's or the file's).
    """
    given = {key: value for key, value in dict(
        duration_s=duration_s, ambient_c=ambient_c, initial_c=initial_c, targets=targets,
        seed=seed, plant=plant, gains=gains).items() if value is not None}
    cli = _Table(given, OVERRIDES_SOURCE, "", tuple(given))
    changes: dict[str, Any] = {}
    events = list(scenario.events)
    if duration_s is not None:
        changes["duration_s"] = _read_duration(cli)
        events = [event for event in events if event.at_s <= changes["duration_s"]]
    starts_c = dict(scenario.initial_c)
    if ambient_c is not None:
        changes["ambient_c"] = cli.number("ambient_c", *AMBIENT_RANGE_C)
        starts_c = {heater: changes["ambient_c"] if temp_c == scenario.ambient_c else temp_c
                    for heater, temp_c in starts_c.items()}
    changes["initial_c"] = starts_c | _read_initial(cli)
    new_targets = cli.table("targets", HEATERS)
    for heater in new_targets.data:
        target_c = new_targets.whole(heater, *TARGET_RANGE_C)
        first = next((i for i, event in enumerate(events)
                      if event.kind == "target" and event.heater == heater), None)
        if first is None:
            events.insert(0, Event(0.0, "target", heater, target_c))
        else:
            events[first] = dataclasses.replace(events[first], value=target_c)
    new_gains = cli.table("gains", HEATERS)
    for heater in new_gains.data:
        value = _read_gains(new_gains.table(heater, ("kp", "ki", "kd")))
        events = [Event(0.0, "gains", heater, value)] + [
            event for event in events if not (event.kind == "gains" and event.heater == heater and event.at_s == 0)]
    changes["events"] = tuple(events)
    if seed is not None:
        changes["seed"] = _read_seed(cli)
    new_plant = _read_plant(cli)
    changes["plant"] = {heater: scenario.plant.get(heater, {}) | new_plant.get(heater, {})
                        for heater in {**scenario.plant, **new_plant}}
    return dataclasses.replace(scenario, **changes)


# Built-in scenarios. Marlin 2.1 defaults behind the expected reactions: hotend runaway period
# 40 s and hysteresis 4 degC, MAXTEMP 275 degC, MINTEMP 5 degC (firmware_port/marlin/constants.py).
_PRESET_TOML = {
    "heat_hold": """
        description = "Heat the hotend to 210 C and the bed to 60 C from cold, then hold."
        duration_s = 600
        [[setpoint]]
        at_s = 0
        heater = "hotend"
        target_c = 210
        [[setpoint]]
        at_s = 0
        heater = "bed"
        target_c = 60
        """,
    "fan_kick": """
        description = "Hold the hotend at 210 C; the part fan goes to 100 % at 300 s."
        duration_s = 600
        [[setpoint]]
        at_s = 0
        heater = "hotend"
        target_c = 210
        [[fan]]
        at_s = 300
        speed = 1.0
        """,
    "extrusion_start": """
        description = "Hold the hotend at 210 C; from 300 s, 1.75 mm filament feeds at 4.2 mm/s (10 mm^3/s)."
        duration_s = 600
        [[setpoint]]
        at_s = 0
        heater = "hotend"
        target_c = 210
        [[flow]]
        at_s = 300
        mm_s = 4.2
        """,
    "cartridge_falls_out": """
        description = "Hold the hotend at 210 C; the heater cartridge falls out at 300 s."
        duration_s = 600
        [[setpoint]]
        at_s = 0
        heater = "hotend"
        target_c = 210
        [[fault]]
        at_s = 300
        heater = "hotend"
        kind = "heater_disconnected"
        """,
    "thermistor_falls_out": """
        description = "Hold the hotend at 210 C; the thermistor slips out of the block at 300 s."
        duration_s = 600
        [[setpoint]]
        at_s = 0
        heater = "hotend"
        target_c = 210
        [[fault]]
        at_s = 300
        heater = "hotend"
        kind = "thermistor_detached"
        """,
}
PRESETS: dict[str, Scenario] = {
    name: parse_scenario(f'name = "{name}"\n' + textwrap.dedent(text), f"preset {name}")
    for name, text in _PRESET_TOML.items()
}


def scenario_for(name_or_path: str) -> Scenario:
    """A preset by name, or the scenario file at a path."""
    if name_or_path in PRESETS:
        return PRESETS[name_or_path]
    if Path(name_or_path).exists():
        return load_scenario(name_or_path)
    raise ScenarioError(f"{name_or_path}: neither a preset name nor an existing scenario file"
                        + _suggest(name_or_path, tuple(PRESETS)))
