"""A printer.cfg's own [thermistor NAME] sections (three points, or one and a beta) on the twin board: read as
klippy's thermistor.py reads them, and a curve that bends the other way (c3 < 0) inverted on the part's root."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.thermistor import SteinhartHart
from protocol.klipper_mcu.board import TwinBoard
from protocol.klipper_mcu.user_config import ConfigError, read_user_config
from tests.klipper_mcu.host import NO_SCENARIO
from tests.klipper_mcu.test_user_config import ENDER3, write

ROBO3D_BED = ((25.0, 100000.0), (50.0, 29536.0), (125.0, 1908.0))  # printer-robo3d-r2-2017.cfg: c3 < 0
OWN = ENDER3.replace("sensor_type: EPCOS 100K B57560G104F\nsensor_pin: PA6", "sensor_type: my bed\nsensor_pin: PA6") + (
    "\n[thermistor my bed]\n" + "".join(f"temperature{k}: {t}\nresistance{k}: {r}\n"
                                        for k, (t, r) in enumerate(ROBO3D_BED, start=1)))


def test_a_configs_own_thermistor_reads_the_ambient(tmp_path):
    config = read_user_config(write(tmp_path, OWN))
    assert config.thermistors["my bed"].points == ROBO3D_BED
    board = TwinBoard.for_config(config, NO_SCENARIO)
    r = float(SteinhartHart.from_points(ROBO3D_BED).resistance_ohm(NO_SCENARIO.ambient_c))
    assert NO_SCENARIO.ambient_c != 25.0 or r == pytest.approx(1e5)  # the curve's own point
    assert board.adc("PA6", 0) == int(np.floor(1024 * r / (r + 4600.0)))  # the bed's 4600 ohm pull-up


def test_a_beta_thermistor(tmp_path):
    text = OWN.replace("temperature2: 50.0\nresistance2: 29536.0\ntemperature3: 125.0\nresistance3: 1908.0\n",
                       "beta: 3950\n")
    config = read_user_config(write(tmp_path, text))
    assert config.thermistors["my bed"].beta == 3950.0
    r = float(SteinhartHart.from_beta(1e5, 3950.0, 25.0).resistance_ohm(NO_SCENARIO.ambient_c))
    assert TwinBoard.for_config(config, NO_SCENARIO).adc("PA6", 0) == int(np.floor(1024 * r / (r + 4600.0)))


def test_points_no_curve_passes_through_are_one_line(tmp_path):
    text = OWN.replace("temperature2: 50.0\nresistance2: 29536.0", "temperature2: 25.0\nresistance2: 100000.0")
    with pytest.raises(ConfigError, match=r"\[thermistor my bed\]: not a thermistor") as error:
        TwinBoard.for_config(read_user_config(write(tmp_path, text)), NO_SCENARIO)
    assert "\n" not in str(error.value)


@given(st.floats(0.0, 300.0))
def test_a_curve_with_negative_c3_inverts_on_its_own_root(temp_c):
    part = SteinhartHart.from_points(ROBO3D_BED)
    assert part.c3 < 0
    assert part.temp_c(float(part.resistance_ohm(temp_c))) == pytest.approx(temp_c, abs=1e-6)
