"""What the data cannot tell: which fitted parameters a log identifies, and for those it does not,
a physically plausible range with its source.

A parameter is identified when its standard error is at most POORLY_IDENTIFIED_REL of its value;
poorly identified up to UNIDENTIFIED_REL; not identified beyond that, on a bound (no standard
error) or undetermined (infinite). Held parameters are not identified either when they are held
by assumption (the cartridge's heat capacity, an ambient nobody measured).

The plausible ranges: the values this project knows for the parameter (Marlin's MPC defaults, the
fits of the captures in hardware_logs, RepRapFirmware's FOPDT models of a Prusa MK3S), from half
the smallest to twice the largest, per heater kind (hotend or bed), each with that list as its
source. A heater's power is not among them: a log fixes P/C and P/A, so a plant with P, C and A
scaled together responds the same (tools/ident/fit.py).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from twin.plants import (
    BED_AMBIENT_XFER_W_K,
    BED_HEAT_CAPACITY_J_K,
    BED_POWER_W,
    BED_SENSOR_RESPONSIVENESS_PER_S,
    MK3_AMBIENT_XFER_W_K,
    MK3_HEAT_CAPACITY_J_K,
    MK3_POWER_W,
    MPC_AMBIENT_XFER_FAN255_W_K,
    MPC_AMBIENT_XFER_W_K,
    MPC_BLOCK_HEAT_CAPACITY_J_K,
    MPC_SENSOR_RESPONSIVENESS_PER_S,
    ONION_BLOCK_HEAT_CAPACITY_J_K,
    ONION_CARTRIDGE_XFER_W_K,
    ONION_RADIATING_PARAMS,
    ONION_SENSOR_RESPONSIVENESS_PER_S,
    ONION_AMBIENT_XFER_W_K,
)

POORLY_IDENTIFIED_REL = 0.2  # a standard error above this share of the value: poorly identified
UNIDENTIFIED_REL = 1.0  # beyond the value itself: the data do not identify it
WIDEN = 2.0  # a plausible range runs from the smallest known value / WIDEN to the largest x WIDEN

# RepRapFirmware M303 FOPDT models of a Prusa MK3S on a Duet 3 (hardware_logs
# rrf_m303_fopdt_models_prusa_mk3s_duet3.txt): hotend at fan 0 / 30 / 100 %, and the bed.
RRF_HOTEND_GAIN_C = (830.5, 474.8, 314.3)
RRF_HOTEND_TIME_CONSTANT_S = (217.5, 134.2, 87.8)
RRF_HOTEND_DEAD_TIME_S = (3.5, 2.9, 2.3)
RRF_BED_GAIN_C = 155.3
RRF_BED_TIME_CONSTANT_S = 497.5
RRF_BED_DEAD_TIME_S = 9.2
ROOM_C = (15.0, 35.0)  # a room: 5 C beyond the captures' room readings, 21.4 C (onionheater) to 30 C (the Ender's bed)
ROOM_SOURCE = "a room: 5 C beyond the room readings of the captures in hardware_logs (21.4..30 C)"
RRF = "RepRapFirmware FOPDT models of a Prusa MK3S (hardware_logs rrf_m303_fopdt_models_prusa_mk3s_duet3.txt)"
MARLIN = "Marlin 2.1 MPC defaults"
ONION = "the onionheater pulse fits (twin/plants.py hotend_cartridge)"
BEDS = "the chesleavens bed fit and seed 004's MK3 bed (twin/plants.py bed, bed_mk3)"

# The known values of each parameter, by heater kind, and where they come from.
KNOWN: dict[tuple[str, str], tuple[tuple[float, ...], str]] = {
    ("hotend", "block_heat_capacity_j_k"): (
        (MPC_BLOCK_HEAT_CAPACITY_J_K, ONION_BLOCK_HEAT_CAPACITY_J_K,
         ONION_RADIATING_PARAMS["block_heat_capacity_j_k"]), f"{MARLIN}; {ONION}"),
    ("hotend", "cartridge_xfer_w_k"): (
        (ONION_CARTRIDGE_XFER_W_K, ONION_RADIATING_PARAMS["cartridge_xfer_w_k"]), ONION),
    ("hotend", "sensor_responsiveness_per_s"): (
        (MPC_SENSOR_RESPONSIVENESS_PER_S, ONION_SENSOR_RESPONSIVENESS_PER_S,
         ONION_RADIATING_PARAMS["sensor_responsiveness_per_s"]), f"{MARLIN}; {ONION}"),
    ("hotend", "ambient_xfer_w_k"): (
        (MPC_AMBIENT_XFER_W_K, MPC_AMBIENT_XFER_FAN255_W_K, ONION_AMBIENT_XFER_W_K,
         ONION_RADIATING_PARAMS["ambient_xfer_w_k"]), f"{MARLIN} (fan off and at 255); {ONION}"),
    ("hotend", "gain_c"): (RRF_HOTEND_GAIN_C, RRF),
    ("hotend", "time_constant_s"): (RRF_HOTEND_TIME_CONSTANT_S, RRF),
    ("hotend", "lag1_s"): (RRF_HOTEND_TIME_CONSTANT_S, f"{RRF}: their time constants"),
    ("hotend", "delay_s"): (RRF_HOTEND_DEAD_TIME_S, RRF),
    ("hotend", "lag2_s"): (RRF_HOTEND_DEAD_TIME_S, f"{RRF}: their dead times, which a second lag stands for"),
    ("bed", "block_heat_capacity_j_k"): ((BED_HEAT_CAPACITY_J_K, MK3_HEAT_CAPACITY_J_K), BEDS),
    ("bed", "sensor_responsiveness_per_s"): ((BED_SENSOR_RESPONSIVENESS_PER_S,), BEDS),
    ("bed", "ambient_xfer_w_k"): ((BED_AMBIENT_XFER_W_K, MK3_AMBIENT_XFER_W_K), BEDS),
    ("bed", "gain_c"): ((RRF_BED_GAIN_C, BED_POWER_W / BED_AMBIENT_XFER_W_K, MK3_POWER_W / MK3_AMBIENT_XFER_W_K),
                        f"{RRF}; {BEDS} (P / A)"),
    ("bed", "time_constant_s"): ((RRF_BED_TIME_CONSTANT_S, BED_HEAT_CAPACITY_J_K / BED_AMBIENT_XFER_W_K,
                                  MK3_HEAT_CAPACITY_J_K / MK3_AMBIENT_XFER_W_K), f"{RRF}; {BEDS} (C / A)"),
    ("bed", "lag1_s"): ((RRF_BED_TIME_CONSTANT_S,), f"{RRF}: its time constant"),
    ("bed", "delay_s"): ((RRF_BED_DEAD_TIME_S,), RRF),
    ("bed", "lag2_s"): ((RRF_BED_DEAD_TIME_S,), f"{RRF}: its dead time, which a second lag stands for"),
}
# Held by assumption, with a range of their own.
ASSUMED: dict[str, tuple[float, float, str]] = {
    "cartridge_heat_capacity_j_k": (1.0, 8.0, "held at 2 J/K (a 6 x 20 mm cartridge); the onionheater fit is as "
                                    "good anywhere in 1..8 J/K (python -m tools.validation.plant_check --fit)"),
    "ambient_c": (*ROOM_C, ROOM_SOURCE),
}
UNKNOWN_FACTOR = 4.0  # a parameter no value is known for: a factor this either way of its own


class Range(NamedTuple):
    """A parameter's plausible values and where they come from."""

    name: str
    low: float
    high: float
    source: str


def heater_kind(heater: str) -> str:
    """"bed" for a bed, else "hotend"."""
    return "bed" if "bed" in heater else "hotend"


def identification(value: float, std_error: float) -> str:
    """"identified", "poorly identified" or "not identified", from a value and its standard error
    (NaN: on a bound; inf: the data do not depend on it)."""
    if not math.isfinite(std_error) or abs(std_error) > UNIDENTIFIED_REL * abs(value):
        return "not identified"
    return "poorly identified" if abs(std_error) > POORLY_IDENTIFIED_REL * abs(value) else "identified"


def plausible(name: str, heater: str, value: float) -> Range:
    """The plausible range of a parameter for a heater ("extruder", "heater_bed", ...), with its
    source; a parameter with no known values gets UNKNOWN_FACTOR either way of its own value."""
    if name in ASSUMED:
        return Range(name, *ASSUMED[name])
    known = KNOWN.get((heater_kind(heater), name))
    if known is None:
        return Range(name, value / UNKNOWN_FACTOR, value * UNKNOWN_FACTOR,
                     f"no known values: a factor {UNKNOWN_FACTOR:g} either way of the fitted value")
    values, source = known
    return Range(name, min(values) / WIDEN, max(values) * WIDEN,
                 f"half the smallest to twice the largest of {', '.join(f'{v:.4g}' for v in values)}: {source}")
