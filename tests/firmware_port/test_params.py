"""Parameter spaces: declared bounds are enforced, log-scale search coordinates invert exactly enough,
the firmware builds' spaces build their controllers from their defaults, and held values are what the
integer port holds."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.controller import Controller
from firmware_port.firmwares import FIRMWARES, PARAM_SPACES, param_space
from firmware_port.fuzzy_pi import FuzzyPi
from firmware_port.params import Param, ParamSpace

SPACE = ParamSpace("two", (Param("a", "C", 0.0, 10.0, 1.0), Param("b", "s", 0.01, 100.0, 1.0, log=True)),
                   factory=lambda a, b: None)


@pytest.mark.parametrize("kwargs, message", [
    (dict(low=1.0, high=1.0, default=1.0), "low < high"),
    (dict(low=0.0, high=1.0, default=2.0), "default 2.0 outside"),
    (dict(low=0.0, high=1.0, default=0.5, log=True), "needs low > 0"),
    (dict(low=0.0, high=float("inf"), default=0.5), "finite"),
])
def test_a_bad_parameter_is_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=f"parameter p: .*{message}"):
        Param("p", "", **kwargs)


def test_a_space_checks_its_vectors():
    with pytest.raises(ValueError, match="takes 2 parameters"):
        SPACE.check([1.0])
    with pytest.raises(ValueError, match="parameter b=1000.0 outside 0.01..100 s"):
        SPACE.check([1.0, 1000.0])
    assert SPACE.inside(np.array([[1.0, 1.0], [1.0, np.nan], [-1.0, 1.0], [10.0, 100.0]])).tolist() == \
        [True, False, False, True]
    with pytest.raises(ValueError, match="unique"):
        ParamSpace("dup", (Param("a", "", 0, 1, 0), Param("a", "", 0, 1, 0)), factory=lambda a, b: None)
    with pytest.raises(ValueError, match="kp, ki, kd"):
        ParamSpace("notpid", SPACE.params, factory=lambda a, b: None, pid=True)


@given(st.floats(0.0, 10.0), st.floats(0.01, 100.0))
def test_search_coordinates_invert(a, b):
    x = np.array([a, b])
    z = SPACE.to_search(x)
    assert z[0] == a and z[1] == pytest.approx(np.log10(b))
    np.testing.assert_allclose(SPACE.from_search(z), x, rtol=1e-12)


@pytest.mark.parametrize("name", list(PARAM_SPACES))
@pytest.mark.parametrize("heater", ["hotend", "bed"])
def test_every_tunable_build_makes_its_controller_from_its_defaults(name, heater):
    if (name, heater) == ("mpc", "bed"):
        with pytest.raises(ValueError, match="mpc is a hotend controller"):
            param_space(name, heater)
        return
    space = param_space(name, heater)
    hotend_factory, bed_factory, _ = FIRMWARES[name]
    built = space.make(space.defaults)
    assert isinstance(built, Controller)
    assert type(built) is type((hotend_factory if heater == "hotend" else bed_factory)())
    assert built.update(200 * 32, 210, 0) == (hotend_factory if heater == "hotend" else bed_factory)().update(
        200 * 32, 210, 0)


def test_non_tunable_and_unknown_builds_are_named():
    with pytest.raises(ValueError, match="'bangbang' has no parameters to tune"):
        param_space("bangbang")
    with pytest.raises(ValueError, match="'nope' is not a firmware build"):
        param_space("nope")


@given(st.floats(1.0, 1000.0), st.floats(1 / 32, 64.0), st.floats(1 / 16, 255.0))
def test_fuzzy_pi_parameters_are_held_as_the_integer_port_holds_them(err, derr, du):
    space = param_space("fuzzy_pi", "bed")
    held = space.hold([err, derr, du])
    assert held[0] * 32 == round(held[0] * 32) and held[1] * 32 == round(held[1] * 32)
    assert held[2] * 16 == round(held[2] * 16)
    assert np.all(np.abs(held - [err, derr, du]) <= [1 / 64, 1 / 64, 1 / 32])
    built = space.make([err, derr, du])
    assert isinstance(built, FuzzyPi) and built.err_range_q5 == round(held[0] * 32)
