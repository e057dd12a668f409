"""Seed 003's maximal-stability-degree method: its defining property, a triple root at -J."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tools.tuning.models import model_of
from tools.tuning.msdi import Quasi, characteristic, gains_at, msdi, msdi_gains, roots_right_of, terms
from twin.plants import SPECS

SEED003 = Quasi.third_order_zero(0.72653, 163.40925, (634.10445, 61.55245, 0.50895), 5.0)  # seed 003 eq. (9)


def differences(model: Quasi, gains, s: float, h: float) -> list[float]:
    """D, D', D'' at s by central differences of the quasi-polynomial itself (independent of the
    solver's exact derivative recursion)."""
    d = [characteristic(model, gains, s + k * h).real for k in (-1, 0, 1)]
    return [d[1], (d[2] - d[0]) / (2 * h), (d[2] - 2 * d[1] + d[0]) / h**2]


def sizes(model: Quasi, gains, s: float) -> np.ndarray:
    """The size of each derivative's parts (sum of their magnitudes), orders 0..3: what 'zero' is
    relative to."""
    return np.abs(terms(model, gains, s, 4)).sum(axis=1)


def third_derivative(model: Quasi, gains, s: float) -> float:
    return float(terms(model, gains, s, 4)[3].sum())


@pytest.mark.parametrize("j", [0.05, 0.1, 0.2, 0.36])
def test_triple_root_at_minus_j(j):
    """D(-J) = D'(-J) = D''(-J) = 0 for the gains of J, by finite differences of D (step h = 1e-3 J:
    truncation h^2 / 12 of the fourth derivative and rounding 1e-16 |D| / h^2 both stay under 1e-5
    of the parts' size), while the third derivative is not zero: a triple root, not a quadruple."""
    gains = gains_at(SEED003, j)
    size = sizes(SEED003, gains, -j)
    d = differences(SEED003, gains, -j, 1e-3 * j)
    assert abs(d[0]) < 1e-9 * size[0]
    assert abs(d[1]) < 1e-5 * size[1]
    assert abs(d[2]) < 1e-5 * size[2]
    assert abs(third_derivative(SEED003, gains, -j)) > 1e-3 * size[3]


def test_triple_root_of_a_polynomial_loop_by_numpy_roots():
    """Without dead time D is a polynomial: numpy's roots show the triple root at -J, and the
    argument-principle count agrees with them."""
    model = Quasi(np.array([2.0]), np.polymul(np.polymul([4.0, 1.0], [2.0, 1.0]), [1.0, 1.0]), 0.0)
    j = 0.3
    kp, ki, kd = gains_at(model, j)
    d = np.polyadd(np.polymul([1.0, 0.0], model.den), np.polymul([kd, kp, ki], model.num))
    roots = np.roots(d)
    assert np.count_nonzero(np.abs(roots + j) < 1e-3) == 3
    for sigma in (-j * 1.001, -j * 0.999, 0.0):
        assert roots_right_of(model, (kp, ki, kd), sigma) == int(np.sum(roots.real > sigma))


def test_chosen_j_is_the_common_maximum_a_quadruple_root():
    """The first maximum of kp(J) is also ki's and kd's (their derivatives along J are
    M^-1 (0, 0, third derivative of D at -J)), and there the third derivative vanishes too."""
    result = msdi(SEED003)
    j = result.j
    assert 0.2 < j < 0.3
    for column in range(3):
        for side in (0.98 * j, 1.02 * j):
            assert gains_at(SEED003, side)[column] < result.gains[column]
    assert abs(third_derivative(SEED003, result.gains, -j)) < 1e-6 * sizes(SEED003, result.gains, -j)[3]


def test_the_zero_keeps_a_slow_root_right_of_minus_j():
    """Seed 003's zero at -1/163.4 s: the loop has a real root just left of it, right of -J."""
    result = msdi(SEED003)
    assert result.roots_right == 1
    zero = -1.0 / 163.40925
    # D changes sign between the zero and 2 % beyond it: a real root there
    assert characteristic(SEED003, result.gains, zero).real * characteristic(SEED003, result.gains, 1.02 * zero).real < 0
    # and none in the right half plane: the loop is stable
    assert roots_right_of(SEED003, result.gains, 0.0) == 0


@pytest.mark.slow


def test_msdi_on_the_preset_in_duty_units():
    """The twin's seed003_third preset takes heater duty (input_full_scale 550 of the paper's
    units): the same method on it gives the paper-unit gains divided by 550 (then x 255 as Gains)."""
    paper = msdi(SEED003)
    gains = msdi_gains(model_of(SPECS["seed003_third"]))
    assert gains.duty == pytest.approx(tuple(g / 550.0 for g in paper.gains), rel=1e-4)


@settings(max_examples=25, deadline=None)
@given(lead=st.floats(0.0, 200.0), lag1=st.floats(10.0, 1000.0), lag2=st.floats(1.0, 100.0),
       lag3=st.floats(0.1, 10.0), delay=st.floats(0.5, 30.0), j_fraction=st.floats(0.05, 2.0))
def test_triple_root_for_any_third_order_model(lead, lag1, lag2, lag3, delay, j_fraction):
    """The contract for any model of seed 003's family: the gains of J put D, D', D'' at -J to zero
    (to 1e-8 of their parts' size: the 3 x 3 solve's rounding), wherever the system is regular
    (J away from the zero's rate 1/lead, where the gains have a pole)."""
    model = Quasi.third_order_zero(1.0, lead, (lag1, lag2, lag3), delay)
    j = j_fraction / delay
    assume(lead == 0.0 or abs(j * lead - 1.0) > 0.05)
    gains = gains_at(model, j)
    parts = terms(model, gains, -j, 3)
    assert np.all(np.abs(parts.sum(axis=1)) <= 1e-8 * np.abs(parts).sum(axis=1))
