"""What the data cannot tell (tools/ident/plausible.py, FitResult.identification/spread/spec_with/degenerate)."""

import math

import numpy as np
import pytest

from tools.ident.plausible import KNOWN, WIDEN, identification, plausible
from tools.ident.result import FitResult
from twin.plants import Lumped, TransferFunction


def _fit(model, params, std, fixed, **kw):
    return FitResult(model, params, std, fixed, np.zeros(3), **kw)


@pytest.mark.parametrize("value, std, standing", [
    (10.0, 1.0, "identified"), (10.0, 3.0, "poorly identified"), (10.0, 11.0, "not identified"),
    (10.0, math.nan, "not identified"), (10.0, math.inf, "not identified"), (-5.0, 0.5, "identified")])
def test_identification(value, std, standing):
    assert identification(value, std) == standing


def test_plausible_ranges_span_the_known_values_widened():
    for (kind, name), (values, source) in KNOWN.items():
        r = plausible(name, "heater_bed" if kind == "bed" else "extruder", 1.0)
        assert r.low == pytest.approx(min(values) / WIDEN) and r.high == pytest.approx(max(values) * WIDEN)
        assert source in r.source
    unknown = plausible("cartridge_xfer_w_k", "heater_bed", 2.0)  # no bed value known
    assert (unknown.low, unknown.high) == (0.5, 8.0) and "no known values" in unknown.source


def test_spread_lists_what_the_data_leave_open_with_sources():
    fit = _fit("three_node", {"block_heat_capacity_j_k": 5.0, "cartridge_xfer_w_k": 1.2,
                              "sensor_responsiveness_per_s": 0.8, "ambient_xfer_w_k": 0.075, "initial_c": 210.0},
               {"block_heat_capacity_j_k": 1.5, "cartridge_xfer_w_k": 5.0, "sensor_responsiveness_per_s": math.nan,
                "ambient_xfer_w_k": 0.001, "initial_c": 1.0},
               {"power_w": 40.0, "cartridge_heat_capacity_j_k": 2.0, "ambient_c": 25.0},
               assumed=("cartridge_heat_capacity_j_k", "ambient_c"), anchor_c=210.0)
    spread = {r.name: r for r in fit.spread()}
    assert set(spread) == {"block_heat_capacity_j_k", "cartridge_xfer_w_k", "sensor_responsiveness_per_s",
                           "cartridge_heat_capacity_j_k", "ambient_c"}  # not A (identified), not initial_c, not P
    # poorly: two standard errors (2..8), within the plausible range widened to the fitted value (5 J/K)
    assert spread["block_heat_capacity_j_k"][1:3] == pytest.approx((5.0, 8.0))
    assert "two standard errors" in spread["block_heat_capacity_j_k"].source
    sensor = spread["sensor_responsiveness_per_s"]  # on a bound: the plausible range, widened to its value
    assert sensor.high == 0.8 and sensor.low == pytest.approx(plausible(sensor.name, "extruder", 0.8).low)
    assert "Marlin" in sensor.source and spread["ambient_c"][1:3] == (15.0, 35.0)
    assert fit.degenerate() is None  # the block's capacity is (poorly) identified


def test_spec_with_stays_in_the_ranges_and_keeps_the_measured_hold():
    fit = _fit("fopdt", {"gain_c": 500.0, "time_constant_s": 120.0, "delay_s": 3.0},
               {"gain_c": 10.0, "time_constant_s": 5.0, "delay_s": 0.1}, {"ambient_c": 25.0, "initial_c": 210.0},
               assumed=("ambient_c",), anchor_c=210.0)
    spec = fit.spec_with(time_constant_s=90.0)
    assert isinstance(spec, TransferFunction) and spec.lag1_s == 90.0 and spec.gain == 500.0
    hotter = fit.spec_with(ambient_c=35.0)
    # the relay measured the duty that holds 210 C: (210 - 25) / 500 = (210 - 35) / gain'
    assert hotter.gain == pytest.approx(500.0 * (210.0 - 35.0) / (210.0 - 25.0))
    with pytest.raises(ValueError, match="ambient_c=50.0 is outside its range 15..35"):
        fit.spec_with(ambient_c=50.0)
    with pytest.raises(ValueError, match="has no parameter 'lag9_s'"):
        fit.spec_with(lag9_s=1.0)


def test_spec_with_a_lumped_loss_rescaled():
    fit = _fit("two_node", {"block_heat_capacity_j_k": 10.0, "sensor_responsiveness_per_s": 0.2,
                            "ambient_xfer_w_k": 0.08}, {"block_heat_capacity_j_k": 0.1,
                                                        "sensor_responsiveness_per_s": 0.01,
                                                        "ambient_xfer_w_k": 0.001},
               {"power_w": 40.0, "ambient_c": 25.0}, assumed=("ambient_c",), anchor_c=200.0)
    spec = fit.spec_with(ambient_c=15.0)
    assert isinstance(spec, Lumped)
    assert spec.ambient_xfer_w_k * (200.0 - 15.0) == pytest.approx(0.08 * (200.0 - 25.0))


def test_degenerate_when_no_lag_is_identified():
    fit = _fit("two_node", {"block_heat_capacity_j_k": 100.0, "sensor_responsiveness_per_s": 0.01,
                            "ambient_xfer_w_k": 1.3},
               {"block_heat_capacity_j_k": 1e4, "sensor_responsiveness_per_s": 2.0, "ambient_xfer_w_k": 0.08},
               {"power_w": 220.0, "ambient_c": 24.0})
    assert "identify none of two_node's lags" in fit.degenerate()
