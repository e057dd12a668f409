"""The firmware builds a board can run: which controller drives the hotend and which the bed."""

from __future__ import annotations

from collections.abc import Callable
from typing import NoReturn

from firmware_port.fuzzy_pi import SEED004_BED, SEED004_HOTEND, FuzzyPi, FuzzyPiFloat, fuzzy_pi_space
from firmware_port.fuzzy_pid import FuzzyPid, FuzzyPidFloat, fuzzy_pid_space
from firmware_port.marlin.bangbang import BangBangBed, BangBangHotend
from firmware_port.marlin.mpc import MPC_SEARCH_FACTOR, MpcController, mpc_space
from firmware_port.marlin.pid import BED_GAINS, HOTEND_GAINS, PidFixed, PidGains, pid_space
from firmware_port.marlin.pid_float import PidFloat, pid_float_space
from firmware_port.params import Param, ParamSpace
from firmware_port.seed000 import (
    adaptive_controller,
    adaptive_space,
    fuzzy_controller,
    fuzzy_space,
    gaussian_controller,
    gaussian_space,
)

# The stock printer's Configuration.h: as a vendor puts its own M303 results into DEFAULT_Kp/Ki/Kd
# and DEFAULT_bedKp/Ki/Kd, these are `M303 E0 S210 C8` and `M303 E-1 S60 C8` on the twin's default
# plants (twin/plants.py hotend_stock and bed), each sent to a fresh twin-serial (tests/protocol/
# test_stock_autotune.py re-runs both). Marlin's own example gains (22.2/1.08/114, bed 10/0.023/305.4) are HOTEND_GAINS and
# BED_GAINS: tuned for other heaters, on the default bed they crawl the last degrees and trip the
# heating watch from a warm start.
STOCK_HOTEND_GAINS = PidGains(19.96, 2.06, 48.23)
STOCK_BED_GAINS = PidGains(86.92, 10.40, 484.20)

# name -> (hotend controller factory, bed controller factory, one-line description)
FIRMWARES: dict[str, tuple[Callable, Callable, str]] = {
    "pid": (
        lambda: PidFixed(STOCK_HOTEND_GAINS),
        lambda: PidFixed(STOCK_BED_GAINS),
        "Marlin's PID law in integer fixed point (PIDTEMP + PIDTEMPBED), the stock printer's M303 gains",
    ),
    "pid_float": (
        lambda: PidFloat(STOCK_HOTEND_GAINS),
        lambda: PidFloat(STOCK_BED_GAINS),
        "Marlin's PID law in float32, as Marlin itself computes it, the stock printer's M303 gains",
    ),
    "mpc": (
        MpcController,
        lambda: PidFixed(BED_GAINS),
        "Marlin's MPC (MPCTEMP) on the hotend in float32 with Configuration.h's model (M306); the bed's PID as in pid",
    ),
    "bangbang": (
        BangBangHotend,
        BangBangBed,
        "Marlin without PIDTEMP/PIDTEMPBED: bang-bang, the bed checked every 5 s",
    ),
    "fuzzy_pi": (
        lambda: FuzzyPi(SEED004_HOTEND),
        lambda: FuzzyPi(SEED004_BED),
        "seed 004's fuzzy-like PI in integer arithmetic (hotend and bed presets)",
    ),
    "fuzzy_pi_float": (
        lambda: FuzzyPiFloat(SEED004_HOTEND),
        lambda: FuzzyPiFloat(SEED004_BED),
        "seed 004's fuzzy-like PI in float, the oracle of fuzzy_pi",
    ),
    "fuzzy_pid": (
        lambda: FuzzyPid(HOTEND_GAINS),
        lambda: FuzzyPid(BED_GAINS),
        "seed 001's fuzzy-PID in integer arithmetic, incremental reading on Marlin's default gains",
    ),
    "fuzzy_pid_float": (
        lambda: FuzzyPidFloat.board(HOTEND_GAINS),
        lambda: FuzzyPidFloat.board(BED_GAINS),
        "seed 001's fuzzy-PID in float, the oracle of fuzzy_pid",
    ),
    "seed000_fuzzy": (
        fuzzy_controller,
        fuzzy_controller,
        "seed 000's fuzzy gain-scheduled PID (triangular sets, five rules, no clamps), float",
    ),
    "seed000_gauss": (
        gaussian_controller,
        gaussian_controller,
        "seed 000's Gaussian fuzzy gain-scheduled PID (integral +-50, output +-100 = full power), float",
    ),
    "seed000_adaptive": (
        adaptive_controller,
        adaptive_controller,
        "seed 000's adaptive PI-D (anti-windup, output clipped at 1.5 x target = full power), float",
    ),
}


def build_controllers(name: str):
    """Fresh (hotend, bed) controllers of a firmware build; ValueError names the valid ones."""
    try:
        hotend, bed, _ = FIRMWARES[name]
    except KeyError:
        raise ValueError(f"unknown firmware {name!r}; choose one of: {', '.join(FIRMWARES)}") from None
    return hotend(), bed()


KALICO_MPC = "kalico_mpc"
KALICO_SAVED_DIGITS = 6  # SAVE_CONFIG writes MPC_CALIBRATE's constants as %#.6g (firmware_port/kalico/save_config.py)


def kalico_mpc_space() -> ParamSpace:
    """Kalico's MPC (``control: mpc``, firmware_port/kalico/mpc.py) as a tunable family: the constants
    MPC_CALIBRATE measures, named as Kalico's section names them, and the part fan's transfer at full speed
    (with ``cooling_fan``: the table ``fan_ambient_transfer: <ambient_transfer>, <this>``). Kalico's MPC is
    Marlin's model on the host and has no defaults of its own, so the defaults and the bounds (1/10 .. 10 x)
    are Marlin's Configuration.h model's; heater_power is the heater's own, not tuned. A tuner builds
    Kalico's section from the parameters on the kalico loop (tools/tuning/evaluate.py ``klipper_setup``):
    there is no board controller to make."""
    marlin = mpc_space()
    c, r, a, f = marlin.defaults
    values = (("block_heat_capacity", "J/K", c), ("sensor_responsiveness", "1/s", r),
              ("ambient_transfer", "W/K", a), ("fan_ambient_transfer", "W/K", a + f))
    params = tuple(Param(name, unit, value / MPC_SEARCH_FACTOR, value * MPC_SEARCH_FACTOR, value, log=True)
                   for name, unit, value in values)

    def held(*constants: float) -> tuple[float, ...]:
        return tuple(float(f"{value:.{KALICO_SAVED_DIGITS}g}") for value in constants)

    return ParamSpace(KALICO_MPC, params, _kalico_host_only, held=held, autotune="MPC_CALIBRATE")


def _kalico_host_only(*constants: float) -> NoReturn:
    raise ValueError(f"{KALICO_MPC} is Kalico's host control: it runs on the kalico loop, not on Marlin's board")


HEATERS = ("hotend", "bed")
# name -> (hotend space, bed space): the builds whose controllers have parameters to tune, each
# space's defaults being what the build runs on that heater.
PARAM_SPACES: dict[str, tuple[Callable[[], ParamSpace], Callable[[], ParamSpace]]] = {
    "pid": (lambda: pid_space(STOCK_HOTEND_GAINS), lambda: pid_space(STOCK_BED_GAINS)),
    "pid_float": (lambda: pid_float_space(STOCK_HOTEND_GAINS), lambda: pid_float_space(STOCK_BED_GAINS)),
    "fuzzy_pi": (lambda: fuzzy_pi_space(SEED004_HOTEND), lambda: fuzzy_pi_space(SEED004_BED)),
    "fuzzy_pi_float": (lambda: fuzzy_pi_space(SEED004_HOTEND, integer=False),
                       lambda: fuzzy_pi_space(SEED004_BED, integer=False)),
    "fuzzy_pid": (lambda: fuzzy_pid_space(HOTEND_GAINS), lambda: fuzzy_pid_space(BED_GAINS)),
    "fuzzy_pid_float": (lambda: fuzzy_pid_space(HOTEND_GAINS, integer=False),
                        lambda: fuzzy_pid_space(BED_GAINS, integer=False)),
    "seed000_fuzzy": (fuzzy_space, fuzzy_space),
    "seed000_gauss": (gaussian_space, gaussian_space),
    "seed000_adaptive": (adaptive_space, adaptive_space),
    "mpc": (mpc_space, lambda: _hotend_only("mpc", "Marlin's MPCTEMP: the bed runs PID or bang-bang")),
}
# name -> (hotend space, bed space): controls a printer's host runs (Kalico's, on the kalico loop), no board's
HOST_SPACES: dict[str, tuple[Callable[[], ParamSpace], Callable[[], ParamSpace]]] = {
    KALICO_MPC: (kalico_mpc_space, lambda: _hotend_only(KALICO_MPC, "its bounds are a hotend's")),
}


def _hotend_only(name: str, why: str) -> ParamSpace:
    raise ValueError(f"{name} is a hotend controller ({why})")


def param_space(name: str, heater: str = "hotend") -> ParamSpace:
    """The tunable parameters of a firmware build's controller (or a host's control) on a heater; ValueError
    names the valid ones."""
    if heater not in HEATERS:
        raise ValueError(f"heater must be one of {', '.join(HEATERS)}, not {heater!r}")
    spaces = {**PARAM_SPACES, **HOST_SPACES}
    if name not in spaces:
        why = "has no parameters to tune" if name in FIRMWARES else "is not a firmware build"
        raise ValueError(f"{name!r} {why}; tunable: {', '.join(spaces)}")
    return spaces[name][HEATERS.index(heater)]()
