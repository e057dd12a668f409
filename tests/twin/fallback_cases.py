"""The batch runs tests/twin/test_fallback.py compares: every plant kind x every lane law, with and without
ADC noise, on the Marlin batch (``BatchTwin``) and the Klipper and Kalico batches (``KlipperBatch``).

``python -m tests.twin.fallback_cases OUT.npz`` runs them all and saves every array a run gives (readings,
records, trips, score totals, the kernel that ran): the test runs it without numba's JIT
(NUMBA_DISABLE_JIT=1, HEATER_TWIN_KERNEL=numpy) and compares with the same runs compiled in its own process.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Callable

import numpy as np

from firmware_port.fuzzy_pi import SEED004_HOTEND, FuzzyPi
from firmware_port.fuzzy_pid import FuzzyPid
from firmware_port.marlin.bangbang import BangBangHotend
from firmware_port.marlin.mpc import MpcController, mpc_controller
from firmware_port.marlin.pid import PidGains
from tests.helpers.integer_pi import IntegerPi
from twin.batch import BatchTwin
from twin.klipper_batch import KlipperBatch, gains_setups
from twin.klipper_twin import extruder_setup, kalico_extruder_setup
from twin.plants import ONION_RADIATING_PARAMS, make_plant
from twin.streaming import ScoreSpec

TARGET_C = 210
DURATION_S = 120.0
HEATUP_END_S = 60.0
FAN_AT_S, FLOW_AT_S = 70.0, 90.0  # the part fan at half, then 4 mm/s of filament (MPC reads both off the board)
# Each kind of plant the batch runs: linear, dead time (seed 003's third order, 5 s), radiating.
PLANTS: dict[str, Callable] = {
    "linear": lambda: make_plant("hotend_cartridge", initial_c=150.0),
    "dead time": lambda: make_plant("seed003_third"),
    "radiating": lambda: make_plant("hotend_cartridge", initial_c=150.0, **ONION_RADIATING_PARAMS),
}
# Every lane law (firmware_port/lane_law.py), two or three lanes each: each law's own parameters differ per lane.
LAWS: dict[str, Callable[[], list]] = {
    "pid": lambda: [PidGains(22.2, 1.08, 114.0), PidGains(40.0, 3.0, 60.0), PidGains(8.0, 0.05, 100.0)],
    "bang-bang": lambda: [BangBangHotend(), BangBangHotend()],
    "fuzzy PI": lambda: [FuzzyPi(SEED004_HOTEND), FuzzyPi(SEED004_HOTEND.__class__(30.0, 1.0, 16.0))],
    "fuzzy-PID": lambda: [FuzzyPid(), FuzzyPid(PidGains(30.0, 2.0, 80.0))],
    "mpc": lambda: [MpcController(), mpc_controller(40.0, 14.0, 0.12, 0.08, 0.12, 0.0056)],
    "user PI": lambda: [IntegerPi(20.0, 1.0), IntegerPi(35.0, 2.5, 0.5)],
}
KLIPPER_LAWS: dict[str, Callable] = {"klipper": extruder_setup, "kalico": kalico_extruder_setup}
KLIPPER_GAINS = np.array([[22.2, 1.08, 114.0], [30.0, 2.0, 50.0]])
NOISES: dict[str, dict] = {"quiet": {}, "noisy": {"noise_lsb": [1.0, 2.5, 1.0], "seed": [3, 3, 7]}}


def _set_inputs(batch, fan: float, flow_mm_s: float) -> None:
    for plant in batch.plants:
        plant.set_inputs(fan, flow_mm_s, plant.ambient_c)


def marlin_run(plant: str, law: str, noise: str) -> dict[str, np.ndarray]:
    """One Marlin batch on the default kernel: a target, the fan, the flow; its records, trips and score."""
    controllers = LAWS[law]()
    n = len(controllers)
    options = {name: value[:n] for name, value in NOISES[noise].items()}
    batch = BatchTwin(PLANTS[plant](), controllers, score=ScoreSpec(TARGET_C, 150.0, HEATUP_END_S, 2.0, 1),
                      **options)
    batch.set_target(TARGET_C)
    batch.schedule(FAN_AT_S, lambda b: _set_inputs(b, 0.5, 0.0))
    batch.schedule(FLOW_AT_S, lambda b: _set_inputs(b, 0.5, 4.0))
    batch.run_until(DURATION_S)
    hotend = batch.result().hotend
    out = {name: getattr(hotend, name) for name in ("t_s", "measured_c", "duty", "block_c", "sensor_c")}
    totals = batch.score_totals()
    out.update({f"score {f.name}": np.asarray(getattr(totals, f.name)) for f in dataclasses.fields(totals)})
    out["halted"], out["trips"] = batch.halted, np.array([str(t) for t in batch.trips()], dtype=str)
    out["state"] = batch.law.read_state(batch.lanes.control)
    out["kernel"] = np.array(batch.kernel)
    return out


def klipper_run(plant: str, law: str, noise: str) -> dict[str, np.ndarray]:
    """One Klipper (or Kalico) batch: its records and shutdowns."""
    setups = gains_setups(KLIPPER_LAWS[law](PLANTS[plant]()), KLIPPER_GAINS)
    options = NOISES[noise]
    if options:
        setups = [dataclasses.replace(s, noise_lsb=n) for s, n in zip(setups, options["noise_lsb"])]
    batch = KlipperBatch(setups, seed=options.get("seed", [0, 0, 0])[:len(setups)], threads=1)
    batch.set_target(float(TARGET_C))
    batch.schedule(FAN_AT_S, lambda b: _set_inputs(b, 0.5, 0.0))
    batch.run_until(DURATION_S)
    hotend = batch.result().hotend
    out = {name: getattr(hotend, name) for name in ("t_s", "measured_c", "duty", "block_c", "sensor_c")}
    out["halted"] = np.asarray(batch.halted)
    return out


def cases() -> dict[str, Callable[[], dict[str, np.ndarray]]]:
    """Every run by name: plant kind x law x noise, Marlin's laws and Klipper's."""
    runs: dict[str, Callable[[], dict[str, np.ndarray]]] = {}
    for plant in PLANTS:
        for noise in NOISES:
            for law in LAWS:
                runs[f"{plant}|{law}|{noise}"] = functools.partial(marlin_run, plant, law, noise)
            for law in KLIPPER_LAWS:
                runs[f"{plant}|{law}|{noise}"] = functools.partial(klipper_run, plant, law, noise)
    return runs


def main(path: str) -> None:
    arrays = {f"{name}#{key}": value for name, run in cases().items() for key, value in run().items()}
    np.savez(path, **arrays)  # type: ignore[arg-type]  # (numpy's stub types the first keyword as allow_pickle)


if __name__ == "__main__":
    main(sys.argv[1])
