"""tools/ident/response.py against the twin's own stepping: the breakpoint-to-breakpoint response equals
the plant advanced tick map by tick map, and the radiating grid's interpolation stays within its bound of
a linearisation at every sample."""

import dataclasses

import numpy as np
import pytest
import scipy.linalg

from tools.ident.response import RADIATING_MAP_STEP_C, radiating_response, zoh_response
from twin.linear import SENSOR, TICK_S
from twin.plants import SPECS, Lumped, Plant, TransferFunction

AMBIENT_C = 22.0


def stepped_by_the_plant(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The reference: LinearPlant.advance over each sample interval, as the engine steps a plant."""
    ticks = np.rint((t_s - t_s[0]) / TICK_S).astype(int)
    out = [plant.temps_c()[SENSOR]]
    for i, n in enumerate(np.diff(ticks)):
        plant.advance(np.full(n, duty[i]))
        out.append(plant.temps_c()[SENSOR])
    return np.array(out)


def log_like(rng: np.random.Generator, n: int, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Irregular sample instants (a host's jitter) and a duty that steps between levels, as a log's."""
    t_s = np.cumsum(np.r_[0.0, period_s + rng.uniform(-0.05, 0.05, n - 1) * period_s])
    duty = np.repeat(rng.choice([0.0, 0.3, 1.0], n // 10 + 1), 10)[:n]
    return t_s, duty


@pytest.mark.parametrize("spec", [
    dataclasses.replace(SPECS["hotend_cartridge"], emissivity=0.0),
    TransferFunction(300.0, 1.0, lag1_s=120.0, delay_s=3.7),
    TransferFunction(80.0, 1.0, lag1_s=60.0, lag2_s=9.0, delay_s=0.4),
], ids=["three_node", "fopdt_delay", "sopdt_delay"])
def test_the_response_equals_the_plant_stepped_tick_map_by_tick_map(spec):
    t_s, duty = log_like(np.random.default_rng(3), 300, 1.0)
    fast, reference = Plant("f", spec, AMBIENT_C, 40.0), Plant("r", spec, AMBIENT_C, 40.0)
    for part in (slice(0, 150), slice(149, 300)):  # two calls: the second continues the first's state and history
        got = zoh_response(fast, t_s[part], duty[part])
        want = stepped_by_the_plant(reference, t_s[part], duty[part])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast.x, reference.x, rtol=0, atol=1e-8)
    np.testing.assert_array_equal(fast._u_history, reference._u_history)


def linearised_at_every_sample(plant: Plant, t_s: np.ndarray, duty: np.ndarray) -> np.ndarray:
    """The reference: one exponential per sample interval, the model linearised at the block then."""
    spec = plant.spec
    assert isinstance(spec, Lumped)
    x, n = plant.x.copy(), len(plant.x)
    out = [plant.temps_c()[SENSOR]]
    ticks = np.rint((t_s - t_s[0]) / TICK_S)
    for i, step_ticks in enumerate(np.diff(ticks)):
        lti = spec.lti(spec.conditions(0.0, 0.0, plant.ambient_c, float(x[0]))._replace(block_bin_c=float(x[0])))
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n], aug[:n, n] = lti.a, lti.b * duty[i] + lti.e @ plant.d
        x = (scipy.linalg.expm(aug * step_ticks * TICK_S) @ np.r_[x, 1.0])[:n]
        out.append(lti.c[SENSOR] @ x)
    return np.array(out)


def test_the_radiating_grid_stays_within_its_bound_of_a_linearisation_at_every_sample():
    """A heat-up to 250 C and a cooling at 0.3 s samples: within 0.01 C of the per-sample linearisation
    (the grid's error is second order in its 5 C step: 0.002 C measured)."""
    spec = dataclasses.replace(SPECS["hotend"], emissivity=1.0, radiating_area_m2=0.003)  # the fits' scale
    t_s = np.arange(0.0, 600.0, 0.3)
    duty = np.where(t_s < 200.0, 1.0, np.where(t_s < 400.0, 0.35, 0.0))
    got = radiating_response(Plant("g", spec, AMBIENT_C, AMBIENT_C), t_s, duty)
    want = linearised_at_every_sample(Plant("r", spec, AMBIENT_C, AMBIENT_C), t_s, duty)
    assert want.max() > 200.0  # the radiation matters up there
    assert np.max(np.abs(got - want)) < 0.01
    assert RADIATING_MAP_STEP_C == 5.0  # the bound above was measured for this step
