"""Scenario files: the TOML layout, presets, overrides, and one clear error for every bad input."""

import json
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from twin.scenario import (
    FAULT_KINDS,
    HEATERS,
    PRESETS,
    Event,
    ScenarioError,
    dump_scenario,
    load_scenario,
    parse_scenario,
    scenario_for,
    with_overrides,
)

DOCS = Path(__file__).resolve().parents[2] / "docs" / "scenarios.md"
EVENT_FIELDS = {
    "pid": ("at_s", "heater", "kp", "ki", "kd"),
    "setpoint": ("at_s", "heater", "target_c"),
    "fan": ("at_s", "speed"),
    "flow": ("at_s", "mm_s"),
    "ambient": ("at_s", "temp_c"),
    "fault": ("at_s", "kind", "heater"),
}


def parse(text: str):
    return parse_scenario(text, "scenario.toml")


def docs_toml_blocks() -> list[str]:
    return re.findall(r"```toml\n(.*?)```", DOCS.read_text(encoding="utf-8"), re.S)


# --- presets and the documented example ------------------------------------------------------


@pytest.mark.parametrize("name", PRESETS)
def test_preset_round_trips(name):
    preset = PRESETS[name]
    assert preset.name == name and preset.description
    assert parse_scenario(dump_scenario(preset), "dumped.toml") == preset


def test_presets_do_what_their_names_say():
    def events(name):
        return [(e.at_s, e.kind, e.heater, e.value) for e in PRESETS[name].events]

    hold = (0.0, "target", "hotend", 210)
    assert events("heat_hold") == [hold, (0.0, "target", "bed", 60)]
    assert events("fan_kick") == [hold, (300.0, "fan", None, 1.0)]
    assert events("extrusion_start") == [hold, (300.0, "flow", "hotend", 4.2)]
    assert events("cartridge_falls_out") == [hold, (300.0, "fault", "hotend", "heater_disconnected")]
    assert events("thermistor_falls_out") == [hold, (300.0, "fault", "hotend", "thermistor_detached")]
    assert {preset.duration_s for preset in PRESETS.values()} == {600.0}


def test_docs_example_parses_and_uses_every_table():
    (example,) = docs_toml_blocks()
    scenario = parse_scenario(example, "example.toml")
    assert {event.kind for event in scenario.events} == {"gains", "target", "fan", "flow", "ambient", "fault"}
    assert scenario.plant == {"hotend": {"preset": "hotend", "power_w": 40.0}, "bed": {"power_w": 220.0}}
    assert scenario.initial_c == {"hotend": 25.0, "bed": 25.0} and scenario.seed == 1
    assert parse_scenario(dump_scenario(scenario), "dumped.toml") == scenario


def test_docs_name_every_preset_and_fault():
    text = DOCS.read_text(encoding="utf-8")
    for word in (*PRESETS, *FAULT_KINDS):
        assert f"`{word}`" in text


# --- the layout -------------------------------------------------------------------------------


def test_defaults():
    scenario = parse("duration_s = 60")
    assert scenario.name == "scenario" and scenario.description == ""
    assert scenario.ambient_c == 25.0 and scenario.initial_c == {"hotend": 25.0, "bed": 25.0}
    assert scenario.events == () and scenario.plant == {} and scenario.seed is None


def test_initial_defaults_to_ambient_per_heater():
    scenario = parse("duration_s = 60\nambient_c = 30\n[initial_c]\nhotend = 200")
    assert scenario.initial_c == {"hotend": 200.0, "bed": 30.0}


def test_events_sorted_by_time_then_table_then_file_order():
    scenario = parse("""
        duration_s = 100
        [[fault]]
        at_s = 10
        kind = "fan_failure"
        [[setpoint]]
        at_s = 50
        heater = "hotend"
        target_c = 200
        [[setpoint]]
        at_s = 10
        heater = "hotend"
        target_c = 190
        [[setpoint]]
        at_s = 10
        heater = "hotend"
        target_c = 180
        [[fan]]
        at_s = 0
        speed = 0.5
        """.replace("    ", ""))
    assert [(e.at_s, e.kind, e.value) for e in scenario.events] == [
        (0.0, "fan", 0.5), (10.0, "target", 190), (10.0, "target", 180),
        (10.0, "fault", "fan_failure"), (50.0, "target", 200)]
    assert parse_scenario(dump_scenario(scenario), "dumped.toml") == scenario


def test_inline_array_of_tables_is_the_same_as_double_brackets():
    inline = parse('duration_s = 9\nsetpoint = [{at_s = 1, heater = "bed", target_c = 60.0}]')
    assert inline.events == (Event(1.0, "target", "bed", 60),)


def test_load_scenario_names_the_file(tmp_path):
    path = tmp_path / "my run.toml"
    path.write_text("duration_s = 60\n[[fan]]\nat_s = 1\nspeed = 2\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=re.escape(f"{path}: fan[0].speed: must be in 0..1, got 2")):
        load_scenario(path)
    path.write_text("duration_s = 60\n", encoding="utf-8")
    assert load_scenario(path).name == "my run"


@pytest.mark.parametrize("content, problem", [
    (None, "cannot read"),
    (b"duration_s = 60 # \xff\n", "not UTF-8"),
])
def test_load_scenario_unreadable(tmp_path, content, problem):
    path = tmp_path / "bad.toml"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ScenarioError, match=f"bad.toml: {problem}"):
        load_scenario(path)


def test_scenario_for_preset_file_or_neither(tmp_path):
    assert scenario_for("fan_kick") is PRESETS["fan_kick"]
    path = tmp_path / "run.toml"
    path.write_text(dump_scenario(PRESETS["heat_hold"]), encoding="utf-8")
    assert scenario_for(str(path)) == PRESETS["heat_hold"]
    with pytest.raises(ScenarioError, match='fan_kik: neither a preset name nor an existing scenario '
                                            'file \\(did you mean "fan_kick"\\?\\)'):
        scenario_for("fan_kik")


# --- errors -------------------------------------------------------------------------------------

SETPOINT = '[[setpoint]]\nat_s = {at}\nheater = "{heater}"\ntarget_c = {target}\n'


def setpoints(*entries: tuple) -> str:
    return "duration_s = 600\n" + "".join(
        SETPOINT.format(at=at, heater=heater, target=target) for at, heater, target in entries)


def fault(kind: str, heater: str | None = "hotend") -> str:
    heater_line = "" if heater is None else f'heater = "{heater}"\n'
    return f'duration_s = 600\n[[fault]]\nat_s = 1\nkind = "{kind}"\n' + heater_line


ERRORS = [
    ("name = 'x'\nduration_s = hot", "TOML syntax error: Invalid value (at line 2, column 14)"),
    ("duraton_s = 60", 'unknown field "duraton_s" (did you mean "duration_s"?)'),
    ("duration_s = 60\nzzz = 1", 'unknown field "zzz"; expected one of "name", "description"'),
    ("name = 'x'", "duration_s: missing required field"),
    ("duration_s = -5", "duration_s: must be > 0, got -5"),
    ("duration_s = 0", "duration_s: must be > 0, got 0"),
    ("duration_s = nan", "duration_s: must be a finite number, got nan"),
    ("duration_s = inf", "duration_s: must be a finite number, got inf"),
    ("duration_s = '60'", "duration_s: expected a number, got \"60\""),
    ("duration_s = true", "duration_s: expected a number, got true"),
    ("duration_s = 60\nambient_c = 300", "ambient_c: must be in -40..120, got 300"),
    ("name = 3\nduration_s = 60", "name: expected a string, got 3"),
    ("duration_s = 60\nseed = 1.5", "seed: expected a non-negative integer, got 1.5"),
    ("duration_s = 60\nseed = -1", "seed: expected a non-negative integer, got -1"),
    ("duration_s = 60\n[initial_c]\nnozzle = 20", 'initial_c: unknown field "nozzle"'),
    ("duration_s = 60\n[initial_c]\nbed = 1e9", "initial_c.bed: must be in -40..400, got 1000000000.0"),
    ("duration_s = 60\n[plant.extruder]\npower_w = 1", 'plant: unknown field "extruder"'),
    ("duration_s = 60\nplant = 5", "plant: expected a table ([plant]), got 5"),
    ("duration_s = 60\n[plant.hotend]\npower_w = [40]",
     "plant.hotend.power_w: expected a number or a string, got an array"),
    ("duration_s = 60\n[plant.hotend]\npower_w = inf", "plant.hotend.power_w: must be a finite number"),
    ('duration_s = 60\n[plant.hotend]\n"a\\nb" = {}', 'plant.hotend."a\\nb": expected a number or a string'),
    ('"dura\\ttion_s" = 60', 'unknown field "dura\\ttion_s" (did you mean "duration_s"?)'),
    (setpoints((0, "hotend", 210), (1, "bed", 60), (2, "hotend", '"hot"')),
     'setpoint[2].target_c: expected a number, got "hot"'),
    (setpoints((0, "hotend", 210.5)), "setpoint[0].target_c: must be a whole number, got 210.5"),
    (setpoints((0, "hotend", 401)), "setpoint[0].target_c: must be in 0..400, got 401"),
    (setpoints((0, "hotend", -1)), "setpoint[0].target_c: must be in 0..400, got -1"),
    (setpoints((0, "nozzle", 210)), 'setpoint[0].heater: unknown heater "nozzle"; expected one of'),
    (setpoints((0, "hotnd", 210)), 'setpoint[0].heater: unknown heater "hotnd" (did you mean "hotend"?)'),
    (setpoints((-1, "hotend", 210)), "setpoint[0].at_s: must be >= 0, got -1"),
    (setpoints((0, "hotend", 210), (601, "hotend", 0)),
     "setpoint[1].at_s: 601 s is after the end of the run (duration_s = 600)"),
    ("duration_s = 60\n[[setpoint]]\nheater = 'bed'\ntarget_c = 60", "setpoint[0].at_s: missing required field"),
    ("duration_s = 60\n[[setpoint]]\nat_s = 0\nheater = 'bed'\ntarget = 60",
     'setpoint[0]: unknown field "target" (did you mean "target_c"?)'),
    ("duration_s = 60\n[setpoint]\nat_s = 0", "setpoint: expected an array of tables ([[setpoint]]), got a table"),
    ("duration_s = 60\nsetpoint = [1]", "setpoint[0]: expected a table, got 1"),
    ("duration_s = 60\n[[fan]]\nat_s = 0\nspeed = 1.5", "fan[0].speed: must be in 0..1, got 1.5"),
    ("duration_s = 60\n[[fan]]\nat_s = 0\nspeed = 1\nheater = 'hotend'", 'fan[0]: unknown field "heater"'),
    ("duration_s = 60\n[[flow]]\nat_s = 0\nmm_s = -1", "flow[0].mm_s: must be in 0..25, got -1"),
    ("duration_s = 60\n[[flow]]\nat_s = 0\nmm_s = 1e20", "flow[0].mm_s: must be in 0..25, got 1e+20"),
    ("duration_s = 60\n[[ambient]]\nat_s = 0\ntemp_c = 298.15", "ambient[0].temp_c: must be in -40..120"),
    (fault("melted"), 'fault[0].kind: unknown fault "melted"; expected one of "thermistor_open"'),
    (fault("heater_stuck_on", None), "fault[0].heater: missing required field"),
    (fault("fan_failure"), "fault[0].heater: fan_failure has no heater (it is the part fan)"),
    (fault("thermistor_open", "chamber"), 'fault[0].heater: unknown heater "chamber"'),
    ("duration_s = 60\n[[fault]]\nat_s = 0\nkind = 3", "fault[0].kind: expected a string, got 3"),
    ("duration_s = 10" + "0" * 400, "duration_s: must be a finite number, got 1" + "0" * 36 + "..."),
    ("x = " + "[" * 5000, "TOML syntax error: arrays or tables nested too deeply"),
]


@pytest.mark.parametrize("text, message", ERRORS)
def test_error_names_the_file_and_the_field(text, message):
    with pytest.raises(ScenarioError) as error:
        parse(text)
    assert str(error.value).startswith("scenario.toml: ")
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_every_fault_kind_parses():
    for kind in FAULT_KINDS:
        heater = None if kind == "fan_failure" else "bed"
        assert parse(fault(kind, heater)).events == (Event(1.0, "fault", heater, kind),)


# --- overrides ----------------------------------------------------------------------------------


def test_overrides_replace_the_files_values():
    fan_kick = PRESETS["fan_kick"]
    scenario = with_overrides(fan_kick, duration_s=200, ambient_c=30, seed=7,
                              plant={"hotend": {"power_w": 50}})
    assert (scenario.duration_s, scenario.ambient_c, scenario.seed) == (200.0, 30.0, 7)
    assert scenario.events == fan_kick.events[:1]  # the fan kick at 300 s is past the end
    assert scenario.initial_c == {"hotend": 30.0, "bed": 30.0}
    assert scenario.plant == {"hotend": {"power_w": 50.0}}
    assert with_overrides(fan_kick) == fan_kick


def test_ambient_override_keeps_explicit_initial_temperatures():
    scenario = parse("duration_s = 60\n[initial_c]\nhotend = 150")
    assert with_overrides(scenario, ambient_c=10).initial_c == {"hotend": 150.0, "bed": 10.0}
    assert with_overrides(scenario, ambient_c=10, initial_c={"bed": 40}).initial_c == {
        "hotend": 150.0, "bed": 40.0}


def test_target_override_replaces_the_first_setpoint_or_adds_one_at_zero():
    scenario = parse(setpoints((5, "hotend", 200), (60, "hotend", 220)))
    changed = with_overrides(scenario, targets={"hotend": 240, "bed": 70})
    assert [(e.at_s, e.heater, e.value) for e in changed.events] == [
        (0.0, "bed", 70), (5.0, "hotend", 240), (60.0, "hotend", 220)]
    assert parse_scenario(dump_scenario(changed), "dumped.toml") == changed


def test_plant_override_merges_per_heater():
    scenario = parse('duration_s = 60\n[plant.hotend]\npreset = "hotend"\npower_w = 40')
    changed = with_overrides(scenario, plant={"hotend": {"power_w": 60.0}, "bed": {"power_w": 200}})
    assert changed.plant == {"hotend": {"preset": "hotend", "power_w": 60.0}, "bed": {"power_w": 200.0}}


@pytest.mark.parametrize("overrides, message", [
    ({"duration_s": -1}, "overrides: duration_s: must be > 0, got -1"),
    ({"ambient_c": 500}, "overrides: ambient_c: must be in -40..120, got 500"),
    ({"initial_c": {"nozzle": 20}}, 'overrides: initial_c: unknown field "nozzle"'),
    ({"targets": {"hotend": 500}}, "overrides: targets.hotend: must be in 0..400, got 500"),
    ({"targets": {"extruder": 200}}, 'overrides: targets: unknown field "extruder"'),
    ({"seed": -3}, "overrides: seed: expected a non-negative integer, got -3"),
    ({"plant": {"hotend": {"power_w": [1]}}}, "overrides: plant.hotend.power_w: expected a number or a string"),
])
def test_override_errors_name_the_option(overrides, message):
    with pytest.raises(ScenarioError, match=re.escape(message)):
        with_overrides(PRESETS["heat_hold"], **overrides)


# --- properties ---------------------------------------------------------------------------------


def toml_value(value) -> str:
    """A generated value as TOML (inline tables and arrays), for documents tomllib reads back."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return {"nan": "nan", "inf": "inf", "-inf": "-inf"}.get(repr(value), repr(value))
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(item) for item in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_value(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    return str(value)  # int, date


def toml_document(data: dict) -> str:
    return "".join(f"{toml_value(key)} = {toml_value(value)}\n" for key, value in data.items())


FIELD_NAMES = sorted({"name", "description", "duration_s", "ambient_c", "seed", "preset", "power_w",
                      *EVENT_FIELDS, *(f for fields in EVENT_FIELDS.values() for f in fields)})
WORDS = st.sampled_from([*HEATERS, *FAULT_KINDS, "nozzle", "hot"])
KEYS = st.sampled_from(FIELD_NAMES) | st.text(max_size=6)
SCALARS = st.one_of(st.integers(), st.floats(), st.text(max_size=8), st.booleans(), st.dates(), WORDS)
VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=3)
                      | st.dictionaries(KEYS, inner, max_size=3), max_leaves=8)
PLAUSIBLE = st.one_of(st.integers(-5, 700), st.floats(-5, 700), WORDS, VALUES)
ENTRY = st.dictionaries(st.sampled_from(FIELD_NAMES), PLAUSIBLE, max_size=4)
DOCUMENTS = st.fixed_dictionaries({}, optional={
    "duration_s": PLAUSIBLE, "ambient_c": PLAUSIBLE, "name": PLAUSIBLE, "seed": PLAUSIBLE,
    "initial_c": st.dictionaries(st.sampled_from([*HEATERS, "nozzle"]), PLAUSIBLE, max_size=2) | VALUES,
    "plant": st.dictionaries(st.sampled_from([*HEATERS, "nozzle"]),
                             st.dictionaries(KEYS, PLAUSIBLE, max_size=3), max_size=2) | VALUES,
    **{table: st.lists(ENTRY, max_size=3) | VALUES for table in EVENT_FIELDS},
}).flatmap(lambda known: st.dictionaries(KEYS, VALUES, max_size=1).map(lambda extra: known | extra))


def assert_only_scenario_errors(text: str) -> None:
    """Parsing either fails with a one-line ScenarioError or gives a scenario that round-trips."""
    try:
        scenario = parse(text)
    except ScenarioError as error:
        assert str(error).startswith("scenario.toml: ") and "\n" not in str(error)
        return
    times_s = [event.at_s for event in scenario.events]
    assert times_s == sorted(times_s) and all(0 <= t <= scenario.duration_s for t in times_s)
    assert parse_scenario(dump_scenario(scenario), "dumped.toml") == scenario


@given(st.text())
def test_junk_text_gives_only_scenario_errors(text):
    assert_only_scenario_errors(text)


@given(DOCUMENTS)
def test_random_toml_values_give_only_scenario_errors(document):
    assert_only_scenario_errors(toml_document(document))


@given(st.sampled_from(sorted(PRESETS)), st.data())
def test_mangled_presets_give_only_scenario_errors(name, data):
    text = dump_scenario(PRESETS[name])
    start = data.draw(st.integers(0, len(text)))
    end = data.draw(st.integers(start, min(len(text), start + 12)))
    assert_only_scenario_errors(text[:start] + data.draw(st.text(max_size=8)) + text[end:])


VALID_EVENTS = {
    "pid": st.fixed_dictionaries({"heater": st.sampled_from(HEATERS), "kp": st.floats(0, 1000),
                                  "ki": st.floats(0, 100), "kd": st.floats(0, 5000)}),
    "setpoint": st.fixed_dictionaries({"heater": st.sampled_from(HEATERS), "target_c": st.integers(0, 400)}),
    "fan": st.fixed_dictionaries({"speed": st.floats(0, 1)}),
    "flow": st.fixed_dictionaries({"mm_s": st.floats(0, 25)}),
    "ambient": st.fixed_dictionaries({"temp_c": st.floats(-40, 120)}),
    "fault": st.sampled_from(FAULT_KINDS).flatmap(lambda kind: st.just(
        {"kind": kind} if kind == "fan_failure" else {"kind": kind, "heater": "hotend"})),
}


@given(st.fixed_dictionaries({
    "duration_s": st.just(100), "name": st.text(), "description": st.text(),
    "initial_c": st.fixed_dictionaries({}, optional={h: st.floats(-40, 400) for h in HEATERS}),
    "plant": st.fixed_dictionaries({}, optional={
        h: st.dictionaries(st.text(), st.floats(-1e6, 1e6) | st.text(), max_size=3) for h in HEATERS}),
    **{table: st.lists(st.builds(lambda fields, at_s: {"at_s": at_s, **fields}, strategy,
                                 st.sampled_from([0, 50, 100]) | st.floats(0, 100)), max_size=3)
       for table, strategy in VALID_EVENTS.items()},
}))
def test_valid_documents_parse_sorted_and_round_trip(document):
    scenario = parse(toml_document(document))
    assert len(scenario.events) == sum(len(document[table]) for table in EVENT_FIELDS)
    assert_only_scenario_errors(dump_scenario(scenario))
