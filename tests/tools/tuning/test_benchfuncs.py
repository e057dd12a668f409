"""F1-F23: known minima, the seed-002 checks of printed values, and the report command
(python -m tools.cli.benchfuncs)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.optimize import minimize

from tools.cli import benchfuncs
from tools.seeds import seed002_benchmark as bench002
from tools.tuning.benchfuncs import BENCHMARKS, BY_NAME
from tools.tuning.optim.benchmark import run_all

# The stated minima carry 12-15 significant digits and the minimisers 6: at a minimiser rounded
# to 6 digits a smooth function sits about 1e-9 above its minimum (Shekel: 4e-9).
AT_ARGMIN_TOL = 1e-8


def test_the_23_functions_with_seed_002_dimensions() -> None:
    assert [b.name for b in BENCHMARKS] == [f"F{i}" for i in range(1, 24)]
    assert [b.dims for b in BENCHMARKS] == [30] * 13 + [2, 4, 2, 2, 2, 3, 6, 4, 4, 4]


@pytest.mark.parametrize("bench", [b for b in BENCHMARKS if b.name != "F7"], ids=lambda b: b.name)
def test_known_minimum_at_its_minimiser(bench) -> None:
    value = bench.costs(bench.at_argmin()[None, :], np.random.default_rng(0))[0]
    assert value == pytest.approx(bench.minimum, abs=AT_ARGMIN_TOL, rel=1e-9)
    assert np.all(bench.at_argmin() >= bench.low) and np.all(bench.at_argmin() <= bench.high)


def test_f7_is_its_noise_at_the_origin() -> None:
    bench = BY_NAME["F7"]
    value = bench.costs(np.zeros((1, 30)), np.random.default_rng(5))
    np.testing.assert_allclose(value, np.random.default_rng(5).random(1), rtol=0, atol=0)


@pytest.mark.parametrize("bench", [b for b in BENCHMARKS if b.dims <= 6 or b.name in {"F8", "F12"}], ids=lambda b: b.name)
def test_no_descent_below_the_known_minimum(bench) -> None:
    def scalar(x: np.ndarray) -> float:
        return float(bench.costs(np.clip(x, bench.low, bench.high)[None, :], np.random.default_rng(0))[0])

    start = bench.at_argmin() + 1e-3 * (bench.high - bench.low) * np.random.default_rng(1).uniform(-1, 1, bench.dims)
    result = minimize(scalar, start, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-14, "maxfev": 20000})
    assert result.fun >= bench.minimum - 1e-9 * max(1.0, abs(bench.minimum))


@given(st.sampled_from(BENCHMARKS), st.integers(0, 2**32 - 1))
def test_no_point_of_the_box_beats_the_known_minimum(bench, seed) -> None:
    rng = np.random.default_rng(seed)
    points = rng.uniform(bench.low, bench.high, (64, bench.dims))
    assert np.all(bench.costs(points, rng) >= bench.minimum - 1e-9 * max(1.0, abs(bench.minimum)))


def test_printed_values_below_the_minimum_are_flagged_allowing_for_rounding() -> None:
    assert bench002.printed_half_unit("3.02E-04") == pytest.approx(0.005e-4)
    assert bench002.printed_half_unit("-3.8662") == pytest.approx(0.00005)
    assert bench002.below_minimum(bench002.PRINTED_MEAN["F9"]["OCALO"], 0.0)  # -2.83E-12 for Rastrigin
    assert bench002.below_minimum(bench002.PRINTED_MEAN["F19"]["IALO"], BY_NAME["F19"].minimum)  # -3.8662
    assert bench002.below_minimum(bench002.PRINTED_BEST["F15"]["OCALO"], BY_NAME["F15"].minimum)  # 3.02E-04
    assert not bench002.below_minimum("-1.0316", BY_NAME["F16"].minimum)  # -1.03163 rounds to it
    assert not bench002.below_minimum("0.998", BY_NAME["F14"].minimum)


def test_printed_best_worse_than_worst_is_an_ordering_error() -> None:
    errors = bench002.ordering_errors()
    assert "F19 OCALO: best -3.8615, mean -3.8625, worst -3.8627" in errors
    assert not any(line.startswith("F1 ") for line in errors)


def test_results_do_not_depend_on_the_number_of_workers() -> None:
    settings = {"seed": 3, "population": 6, "iterations": 4}
    alone = run_all(["F16", "F21"], ["pso", "ocalo"], 2, workers=1, **settings)
    spread = run_all(["F16", "F21"], ["pso", "ocalo"], 2, workers=2, **settings)
    assert alone.keys() == spread.keys()
    for key, costs in alone.items():
        np.testing.assert_array_equal(costs, spread[key])  # same seeds, same arithmetic on this CPU


def test_quick_command_writes_the_report(tmp_path, capsys) -> None:
    out = tmp_path / "table.md"
    assert benchfuncs.main(["--quick", "--workers", "1", "--functions", "F1,F9,F16", "--out", str(out)]) == 0
    report = out.read_text()
    assert re.search(r"OCALO beats ALO on \d of 3 \(mean over 2 runs, plain form\)", report)
    rows = [line for line in report.splitlines() if re.match(r"\| F(1|9|16) ", line)]
    assert len(rows) == 6  # one row per function in each table
    assert "F9 OCALO mean -2.83E-12 < known minimum 0" in report
    assert "report written to" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("flags", "message"),
    [(["--runs", "0"], "--runs"), (["--methods", "nm,sa"], "--methods"), (["--functions", "F24"], "--functions"),
     (["--iterations", "2"], "--iterations"), (["--forms", "plain,tilted"], "--forms")],
)  # fmt: skip
def test_bad_flags_get_a_one_line_error(flags, message, capsys) -> None:
    assert benchfuncs.main(flags) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_ocalo_is_pulled_to_the_origin_and_the_shifted_form_exposes_it() -> None:
    # Seed 002's cosine factors end at 0.01 R_A (ocalo.py): ants land near x = 0. On F1 with a
    # tiny budget OCALO reaches ~1e-8 at the origin; with the minimiser moved (shifted form) it
    # stays ~1e4 away, as far as ALO. Margins of 4+ orders of magnitude, not a tolerance on a float.
    settings = {"seed": 0, "population": 10, "iterations": 10, "workers": 1}
    results = run_all(["F1"], ["alo", "ocalo"], 2, forms=("plain", "shifted"), **settings)
    assert results["F1", "ocalo", "plain"].max() < 1e-3 < 1e3 < results["F1", "alo", "plain"].min()
    assert results["F1", "ocalo", "shifted"].min() > 1e3
