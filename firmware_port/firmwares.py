"""The firmware builds a board can run: which controller drives the hotend and which the bed."""

from __future__ import annotations

from collections.abc import Callable

from firmware_port.fuzzy_pi import SEED004_BED, SEED004_HOTEND, FuzzyPi, FuzzyPiFloat
from firmware_port.fuzzy_pid import FuzzyPid, FuzzyPidFloat
from firmware_port.marlin.bangbang import BangBangBed, BangBangHotend
from firmware_port.marlin.mpc import MpcController
from firmware_port.marlin.pid import BED_GAINS, HOTEND_GAINS, PidFixed
from firmware_port.marlin.pid_float import PidFloat
from firmware_port.seed000 import adaptive_controller, fuzzy_controller, gaussian_controller

# name -> (hotend controller factory, bed controller factory, one-line description)
FIRMWARES: dict[str, tuple[Callable, Callable, str]] = {
    "pid": (
        lambda: PidFixed(HOTEND_GAINS),
        lambda: PidFixed(BED_GAINS),
        "Marlin's PID law in integer fixed point (PIDTEMP + PIDTEMPBED)",
    ),
    "pid_float": (
        lambda: PidFloat(HOTEND_GAINS),
        lambda: PidFloat(BED_GAINS),
        "Marlin's PID law in float32, as Marlin itself computes it",
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
