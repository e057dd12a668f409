"""The shifted and rotated forms of F1-F23 (tools/tuning/benchfuncs.variant): same box and minimum,
the minimiser moved off the origin, the landscape rotated about it, reproducible from the seed."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tools.tuning.benchfuncs import BY_NAME, MOVABLE, PLAIN, ROTATED, SHIFT_SPAN, SHIFTED, rotation, variant

MOVED_FORMS = (SHIFTED, ROTATED)
# The value at the moved minimiser is the plain function's at its own minimiser up to the rounding
# of x - m and the rotation (30 coordinates of size <= 600, float64): far below 1e-9.
AT_ARGMIN_TOL = 1e-9


@pytest.mark.parametrize("form", MOVED_FORMS)
@pytest.mark.parametrize("name", [n for n in MOVABLE if n != "F7"])
def test_the_minimum_moves_with_its_value_kept(name, form) -> None:
    bench = variant(name, form)
    at = bench.at_argmin()
    assert bench.costs(at[None, :], np.random.default_rng(0))[0] == pytest.approx(bench.minimum, abs=AT_ARGMIN_TOL)
    assert np.all(np.abs(at) <= SHIFT_SPAN * bench.high) and not np.allclose(at, BY_NAME[name].at_argmin())
    assert bench.bounds == BY_NAME[name].bounds and bench.form == form


@given(st.sampled_from(MOVABLE), st.sampled_from(MOVED_FORMS), st.integers(0, 2**32 - 1))
def test_no_point_of_the_box_beats_the_minimum(name, form, seed) -> None:
    bench = variant(name, form)
    rng = np.random.default_rng(seed)
    points = rng.uniform(bench.low, bench.high, (64, bench.dims))
    assert np.all(bench.costs(points, rng) >= bench.minimum - 1e-9)


def test_a_rotation_is_orthogonal_and_not_the_identity() -> None:
    m = rotation(30, np.random.default_rng(1))
    np.testing.assert_allclose(m @ m.T, np.eye(30), atol=1e-12)
    assert abs(abs(np.linalg.det(m)) - 1) < 1e-9 and not np.allclose(m, np.eye(30))


def test_the_rotated_form_is_not_separable_where_the_shifted_is() -> None:
    # Rastrigin is a sum over coordinates: moving one coordinate of the shifted form changes one
    # term; in the rotated form one coordinate enters every term. Same shift, different landscape.
    shifted, rotated = variant("F9", SHIFTED), variant("F9", ROTATED)
    assert not np.allclose(shifted.at_argmin(), rotated.at_argmin())  # each form draws its own minimiser
    rng = np.random.default_rng(0)
    for bench in (shifted, rotated):
        x = bench.at_argmin().copy()
        x[0] += 0.5  # half a period of the cosine: the term of coordinate 0 alone is 10 + 0.25 = 20.25
        value = bench.costs(x[None, :], rng)[0]
        assert (value == pytest.approx(20.25, abs=1e-9)) == (bench is shifted)


def test_forms_are_reproducible_and_the_plain_form_is_the_function() -> None:
    assert variant("F1", PLAIN) is BY_NAME["F1"]
    variant.cache_clear()
    first = variant("F5", ROTATED).at_argmin()
    variant.cache_clear()
    np.testing.assert_array_equal(first, variant("F5", ROTATED).at_argmin())  # same seed, same draw


def test_undefined_forms_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match="F8 has no shifted form"):
        variant("F8", SHIFTED)
    with pytest.raises(ValueError, match="form must be one of"):
        variant("F1", "tilted")
