"""heater-twin's public API: a firmware twin of a printer's heaters, its result, its plants.

    from twin import Twin, PidGains
    t = Twin.create("pid", hotend="hotend_cartridge")
    t.hotend.target_c = 210
    t.hotend.gains = PidGains(kp=12.6, ki=0.39, kd=103)
    result = t.run(600)                      # RunResult: result.hotend.measured_c, ...
    print(result.hotend.metrics())           # StepMetrics
    result.plot("hotend.png")

``Twin`` runs the integer firmware on one plant per heater; ``BatchTwin`` runs N gain sets as
lanes of one hotend (arrays (rows, lanes)); ``KlipperTwin`` runs Klipper's host control. All
three return a ``RunResult``. Controllers are injected per heater (``controllers=``): anything
with the ``Controller`` protocol, or a factory of one.
"""

import os

# The twin's matrices are 2x2 to 5x5: OpenBLAS's threads only cost there (on a busy 2-core machine a 4x4
# expm took 60 ms with them, 0.05 ms without). Read when numpy loads; a value the user set stays.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from firmware_port.controller import Controller, Tunable
from firmware_port.firmwares import FIRMWARES
from firmware_port.marlin.pid import PidGains
from twin.batch import BatchTwin
from twin.build import build_twin
from twin.engine import HeaterHandle, Twin
from twin.klipper_twin import KlipperTwin
from twin.metrics import LimitCycle, StepMetrics, limit_cycles, step_metrics
from twin.plants import PRESETS, make_plant
from twin.result import HeaterRun, RunResult
from twin.scenario import Scenario, scenario_for

__all__ = [
    "BatchTwin",
    "Controller",
    "FIRMWARES",
    "HeaterHandle",
    "HeaterRun",
    "KlipperTwin",
    "LimitCycle",
    "PRESETS",
    "PidGains",
    "RunResult",
    "Scenario",
    "StepMetrics",
    "Twin",
    "Tunable",
    "build_twin",
    "limit_cycles",
    "make_plant",
    "scenario_for",
    "step_metrics",
]
