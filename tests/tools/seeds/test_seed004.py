"""Seed 004's experiments on the twin: verdicts exactly, numbers within stated tolerances.

The twin is integer firmware on a float plant; its numbers move only if the plant's float
arithmetic moves an ADC sample across a count, so 1 % (or 0.5 C on a reading) covers another
machine's BLAS with a wide margin. The bisections compare against the paper's printed numbers,
so their outcome is a verdict, checked exactly.
"""

import numpy as np
import pytest

from firmware_port.thermistor import Divider, SteinhartHart
from tools.seeds import seed004
from tools.seeds.report import DIFFERS, FITTED, IMPOSSIBLE
from twin.plants import SPECS, Lumped
from twin.sensor import SensorChain


@pytest.fixture(scope="module")
def result():
    """About 25 s of one core: the tests that use it are marked slow."""
    return seed004.reproduce()


@pytest.mark.slow
def test_bed_within_ten_percent_of_the_paper(result):
    """Rise and settling within 10 % of 500 s and 800 s (the acceptance); the peak near 106 C."""
    assert result.bed_rise_within and result.bed_settling_within
    assert result.bed.rise_time_s == pytest.approx(509.3, rel=0.01)
    assert result.bed.settling_time_2pct_s == pytest.approx(817.5, rel=0.01)
    assert result.bed.du_range_counts == 3.625  # bisection outcome on the Q4 grid
    assert result.bed.max_c == pytest.approx(106.7, abs=0.5)
    assert result.bed.steady_c == pytest.approx(105.0, abs=0.1)


@pytest.mark.slow
def test_bed_preset_settles_faster_than_the_paper(result):
    """The SEED004_BED preset (output change +-16 counts) rises as the paper's but settles in
    about 667 s, 17 % short of 800 s: why the output-change range is calibrated."""
    assert result.bed_preset.rise_time_s == pytest.approx(511.6, rel=0.01)
    assert result.bed_preset.settling_time_2pct_s == pytest.approx(667.0, rel=0.01)
    assert not result.bed_preset.within("settling_time_s", result.bed_preset.settling_time_2pct_s)


@pytest.mark.slow
def test_resolution_cannot_explain_26_c(result):
    """One ADC count is 0.60 C at 214 C and 0.92 C at 240 C: 26 C is 28..44 counts."""
    step_214, step_240 = result.adc_step_c
    assert step_214 == pytest.approx(0.595, abs=0.005)
    assert step_240 == pytest.approx(0.923, abs=0.005)


@pytest.mark.slow
def test_extruder_verdicts(result):
    """Only the slow (loosely coupled) sensor reproduces the reading's steady maximum of 240 C; the
    gradient and the calibration error hold the reading at the set point while the nozzle runs
    26 C hot; the as-built hotend holds 214 C."""
    cases = {c.name: c for c in result.extruder}
    assert [c.reproduces for c in result.extruder] == [False, False, False, True]
    assert not any(c.halted for c in result.extruder)
    for name in ("as built", "placement gradient", "calibration error"):
        assert cases[name].reading_steady_max_c == pytest.approx(214.0, abs=1.0)
    for name in ("placement gradient", "calibration error"):
        assert cases[name].nozzle_steady_mean_c == pytest.approx(240.0, abs=1.0)
    slow = cases["loosely coupled bead (slow sensor)"]
    assert slow.reading_steady_max_c == pytest.approx(240.0, abs=1.0)
    assert slow.reading_max_c == pytest.approx(253.6, abs=0.5)
    assert slow.rise_time_s == pytest.approx(120.4, rel=0.01)


@pytest.mark.slow
def test_page_verdicts_call_the_fits_fits(result):
    """The bed's rise (its loss solved from the paper's '10 minutes to 100 C'), the bed's settling (the
    output-change range bisected) and the extruder's steady maximum (the sensor bisected) are fits;
    the extruder's rise, predicted by the same fit, differs; the thermistor's blame is impossible."""
    rows = {(r.experiment.split(", ")[1], r.quantity): r.verdict for r in seed004.verdicts(result)}
    assert rows["bed", "rise time s"] == rows["bed", "settling time 2 % s"] == FITTED
    assert rows["extruder", "steady max C"] == rows["extruder", "steady-state error %"] == FITTED
    assert rows["extruder", "rise time s"] == DIFFERS and rows["extruder", "cause of the excess"] == IMPOSSIBLE


def test_the_extruder_plant_is_the_papers_not_the_projects_default(monkeypatch):
    """A change of the project's `hotend` preset cannot move this paper's numbers: seed 004 builds
    its 40 W cartridge from Marlin's MPC constants itself."""
    monkeypatch.setitem(SPECS, "hotend", Lumped(60.0, 9.0, 0.5, 0.1, 0.1))
    plant = seed004.hotend_plant()
    assert plant.spec == seed004.HOTEND and seed004.HOTEND.power_w == 40.0
    assert plant.preset == seed004.HOTEND_NAME


def test_beta_reading_low_is_exact():
    """A part with the solved beta has, at 240 C, the resistance B3950 has at 214 C."""
    beta = seed004.beta_reading_low(240.0, 214.0)
    part = Divider().part
    wrong = SteinhartHart.from_beta(part.resistance_ohm(25.0), beta)
    assert float(wrong.resistance_ohm(240.0)) == pytest.approx(float(part.resistance_ohm(214.0)), rel=1e-9)


def test_gradient_fraction_scales_the_rise_and_is_validated():
    """The bead sees 1 - g of the node's rise above ambient; at ambient it reads ambient."""
    exact, graded = SensorChain(), SensorChain(gradient_fraction=0.5)
    for chain in (exact, graded):
        chain.set_ambient(25.0, 0)
    ticks = np.zeros(2, dtype=int)
    assert graded.convert(np.array([25.0, 225.0]), ticks).tolist() == exact.convert(np.array([25.0, 125.0]),
                                                                                    ticks).tolist()
    with pytest.raises(ValueError, match="gradient_fraction"):
        SensorChain(gradient_fraction=1.0)
