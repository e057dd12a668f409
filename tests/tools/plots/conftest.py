"""One real tune for the figure tests: the rules on hotend_cartridge (its nominal plant, seeded), proven on one seed,
your gains given."""

from __future__ import annotations

import numpy as np
import pytest

from tools.tuning.evaluate import preset_problem
from tools.tuning.tuner import proven, tune

YOURS = np.array([12.0, 0.4, 100.0])  # Kp, Ki, Kd on Marlin's scale: a printer's, to beat


@pytest.fixture(scope="module")
def tuned():
    result = tune(preset_problem("hotend_cartridge", 210), method="rules", seed=0, yours=YOURS)
    return result, proven(result, 1, cross_check_s=0)
