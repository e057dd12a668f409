"""heater-twin's public API: a firmware twin of a printer's heaters, its result, its plants.

    from twin import Twin, PidGains
    t = Twin.create("pid", hotend="hotend_cartridge")
    t.hotend.target_c = 210
    t.hotend.gains = PidGains(kp=12.6, ki=0.39, kd=103)
    result = t.run(600)                      # RunResult: result.hotend.measured_c, ...
    print(result.hotend.metrics())           # StepMetrics
    result.plot("hotend.png")

``Twin`` runs the integer firmware on one plant per heater; ``BatchTwin`` runs N controllers as
lanes of one hotend (arrays (rows, lanes)); ``KlipperTwin`` runs Klipper's host control and
``KlipperBatch`` N Klipper heaters as lanes. All four follow one ``Engine`` protocol
(twin/engine_protocol.py): per-heater handles (``engine.hotend.target_c``), ``schedule_plants``,
``run(seconds) -> RunResult``, ``halted`` and ``trips()``; a ``Stack`` puts single twins side by
side as lanes. Controllers are injected per heater (``controllers=``): anything with the
``Controller`` protocol, or a factory of one.
"""

import os

# The twin's matrices are 2x2 to 5x5: OpenBLAS's threads only cost there (on a busy 2-core machine a 4x4
# expm took 60 ms with them, 0.05 ms without). Read when numpy loads; a value the user set stays.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from typing import TYPE_CHECKING

# Where each public name lives: imported on first use (PEP 562), so that a command that needs only
# twin.limits or twin.clock does not pay for numba and scipy at start-up (``twin-sim --help``).
_HOMES = {
    "Controller": "firmware_port.controller", "Tunable": "firmware_port.controller",
    "FIRMWARES": "firmware_port.firmwares", "PidGains": "firmware_port.marlin.pid",
    "BatchTwin": "twin.batch", "build_twin": "twin.build", "HeaterHandle": "twin.engine", "Twin": "twin.engine",
    "Engine": "twin.engine_protocol", "Stack": "twin.engine_protocol", "Trip": "twin.engine_protocol",
    "KlipperBatch": "twin.klipper_batch", "KlipperTwin": "twin.klipper_twin",
    "LimitCycle": "twin.metrics", "StepMetrics": "twin.metrics", "limit_cycles": "twin.metrics",
    "step_metrics": "twin.metrics", "PRESETS": "twin.plants", "make_plant": "twin.plants",
    "HeaterRun": "twin.result", "RunResult": "twin.result", "Scenario": "twin.scenario",
    "scenario_for": "twin.scenario",
}

if TYPE_CHECKING:
    from firmware_port.controller import Controller, Tunable
    from firmware_port.firmwares import FIRMWARES
    from firmware_port.marlin.pid import PidGains
    from twin.batch import BatchTwin
    from twin.build import build_twin
    from twin.engine import HeaterHandle, Twin
    from twin.engine_protocol import Engine, Stack, Trip
    from twin.klipper_batch import KlipperBatch
    from twin.klipper_twin import KlipperTwin
    from twin.metrics import LimitCycle, StepMetrics, limit_cycles, step_metrics
    from twin.plants import PRESETS, make_plant
    from twin.result import HeaterRun, RunResult
    from twin.scenario import Scenario, scenario_for

__all__ = [
    "BatchTwin",
    "Controller",
    "Engine",
    "FIRMWARES",
    "HeaterHandle",
    "HeaterRun",
    "KlipperBatch",
    "KlipperTwin",
    "LimitCycle",
    "PRESETS",
    "PidGains",
    "RunResult",
    "Scenario",
    "Stack",
    "StepMetrics",
    "Trip",
    "Twin",
    "Tunable",
    "build_twin",
    "limit_cycles",
    "make_plant",
    "scenario_for",
    "step_metrics",
]


def __getattr__(name: str) -> object:
    """A public name, imported from its module on first use."""
    if name not in _HOMES:
        raise AttributeError(f"module 'twin' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(_HOMES[name]), name)
    globals()[name] = value
    return value
