"""Assemble a twin from a scenario: plants per heater, the firmware build, the scheduled events."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, cast

from firmware_port.controller import ControllerSpec
from firmware_port.marlin.board import BED_CHANNEL, HOTEND_CHANNEL
from firmware_port.marlin.pid import PidGains
from twin.engine import BOOT_S, Twin
from twin.limits import UserError
from twin.plants import DEFAULT_BED, DEFAULT_HOTEND, make_plant
from twin.scenario import Event, Scenario
from twin.sensor import DETACHED, OPEN, SHORT

CHANNELS = {"hotend": HOTEND_CHANNEL, "bed": BED_CHANNEL}
DEFAULT_PRESETS = {"hotend": DEFAULT_HOTEND, "bed": DEFAULT_BED}


def build_twin(
    scenario: Scenario,
    firmware: str = "pid",
    *,
    controllers: Sequence[ControllerSpec | None] = (),
    with_bed: bool = True,
    engine: str = "fast",
    noise_lsb: float = 0.0,
    board_options: dict | None = None,
) -> Twin:
    """A twin ready to run ``scenario``: plants from its [plant] tables, its events scheduled;
    ``controllers`` (per heater: an instance, a factory or None) replace the firmware's."""
    heaters = ("hotend", "bed") if with_bed else ("hotend",)
    plants = []
    for heater in heaters:
        params = dict(scenario.plant.get(heater, {}))
        preset = params.pop("preset", DEFAULT_PRESETS[heater])
        plants.append(
            make_plant(str(preset), ambient_c=scenario.ambient_c, initial_c=scenario.initial_c.get(heater), **params)
        )
    twin = Twin(
        plants,
        firmware,
        controllers=controllers,
        seed=scenario.seed or 0,
        noise_lsb=noise_lsb,
        engine=engine,
        board_options=board_options,
    )
    twin.set_ambient(scenario.ambient_c)
    twin.boot(BOOT_S)
    for event in scenario.events:
        if event.heater == "bed" and not with_bed:
            continue
        if event.kind == "gains" and not twin.board.has_gains(CHANNELS[str(event.heater)]):
            raise UserError(f"{scenario.name}: pid gains for the {event.heater} at {event.at_s:g} s, but firmware "
                             f"{firmware!r} has no PID on that heater")
        twin.schedule(event.at_s, functools.partial(apply_event, event=event))
    return twin


def apply_event(twin: Twin, event: Event) -> None:
    """What a scenario event does to the printer and its world, noted in the trace."""
    # parse_scenario checked each kind's heater and value types
    channel: Any = CHANNELS.get(event.heater) if event.heater else None
    kind, value = event.kind, cast(Any, event.value)
    if kind == "gains":
        twin.board.set_gains(channel, PidGains(*value))
    elif kind == "target":
        twin.board.set_target(channel, int(value))
    elif kind == "fan":
        twin.board.fan_speed = round(255 * float(value))
    elif kind == "flow":
        twin.flow_mm_s = float(value)
    elif kind == "ambient":
        twin.set_ambient(float(value))
    elif kind == "fault":
        if value in (OPEN, SHORT, DETACHED):
            twin.set_thermistor_fault(channel, value)
        elif value == "fan_failure":
            twin.fan_failed = True
        else:
            twin.set_heater_mode(channel, value)
    else:
        raise ValueError(f"unknown scenario event kind {kind!r}")
    where = f" {event.heater}" if event.heater else ""
    twin.trace.add_event(twin.time_s, f"scenario: {kind}{where} {value}")

