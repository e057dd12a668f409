"""The default hotend's row of docs/plants.md's preset table: static rise, holding duty, time constants."""

from __future__ import annotations

import numpy as np
import pytest

from twin.plants import DEFAULT_HOTEND, SPECS, Conditions


def test_the_default_hotends_table_row():
    spec = SPECS[DEFAULT_HOTEND]
    assert DEFAULT_HOTEND == "hotend_stock"
    assert spec.power_w / spec.ambient_xfer_w_k == pytest.approx(588.2, abs=0.1)  # static rise, C
    assert (210 - 25) * spec.ambient_xfer_w_k / spec.power_w == pytest.approx(0.315, abs=0.001)  # duty at 210 C
    eigenvalues = np.linalg.eigvals(spec.lti(Conditions(0.0, 0.0)).a)
    assert sorted(-1 / eigenvalues.real, reverse=True) == pytest.approx([117.9, 4.55, 1.75], abs=0.05)
