"""The 23 classical benchmark functions F1-F23, as seed 002 (the OCALO paper) uses them, and their
shifted and rotated forms.

Definitions follow Yao, Liu and Lin, "Evolutionary programming made faster", IEEE Trans.
Evolutionary Computation 3(2), 1999 (functions f1-f23), the set seed 002 benchmarks on (its
table 1); dimensions and search ranges are seed 002's table 1 (F17 Branin there is on [-5, 5]^2
instead of Yao's [-5, 10] x [0, 15]; its minimum (pi, 2.275) lies inside either). Known global
minima: Yao et al. for F1-F13 (F8: -418.9829 n, at x_i = 420.9687) and F18; the precise values
of F14-F17 and F19-F23 and their minimisers are those of the Virtual Library of Simulation
Experiments (Surjanovic and Bingham, Simon Fraser University), checked by the tests (the value
at the stated minimiser, and no local descent below it). F7 adds uniform noise in [0, 1) drawn
from the caller's Generator, so its minimum 0 is an infimum.

Every function maps a population (rows) to costs, the optimisers' batch contract.

Shifted and rotated forms (``variant``), as the CEC suites build them (Suganthan et al., "Problem
definitions and evaluation criteria for the CEC 2005 special session on real-parameter
optimization", 2005): F(x) = f(a + M (x - m)), with a the function's own minimiser, m the new
minimiser drawn uniformly in SHIFT_SPAN x the box (CEC 2005: o_i in [-80, 80] on [-100, 100]),
and M the identity (shifted) or a random rotation (rotated: the Q of a QR decomposition of a
standard normal matrix, its columns' signs fixed by R's diagonal, a uniform draw from the
orthogonal group). Same box, same minimum value, the minimum no longer at the origin or on the
box's diagonal. m and M come from ``numpy.random.default_rng([FORM_SEED, form, function])``.
Defined for the scalable F1-F7 and F9-F13, whose minimum over all of R^n is the box's (so a
point of the box that maps outside it cannot beat the minimum); not for F8, whose Schwefel
landscape falls below its stated minimum outside [-500, 500], nor for the fixed-dimension
F14-F23 (their data fix the landscape, as in the CEC suites, which shift only scalable functions).

``python -m tools.cli.benchfuncs`` runs every optimiser on them and writes the report.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

Costs = Callable[[np.ndarray, np.random.Generator], np.ndarray]


@dataclass(frozen=True)
class Benchmark:
    """One test function: its search box, known global minimum and a minimiser."""

    name: str
    title: str
    dims: int
    low: float
    high: float
    minimum: float
    argmin: tuple[float, ...]
    costs: Costs
    form: str = "plain"

    @property
    def bounds(self) -> list[tuple[float, float]]:
        return [(self.low, self.high)] * self.dims

    def at_argmin(self) -> np.ndarray:
        point = np.array(self.argmin, dtype=float)
        return np.full(self.dims, point[0]) if point.size == 1 else point


def _penalty(x: np.ndarray, a: float, k: float, m: float) -> np.ndarray:
    """Yao et al.'s u(x, a, k, m): k (|x| - a)^m outside [-a, a], summed over each row."""
    return np.sum(k * np.maximum(np.abs(x) - a, 0.0) ** m, axis=1)


def f1(x, rng):
    return np.sum(x**2, axis=1)


def f2(x, rng):
    return np.sum(np.abs(x), axis=1) + np.prod(np.abs(x), axis=1)


def f3(x, rng):
    return np.sum(np.cumsum(x, axis=1) ** 2, axis=1)


def f4(x, rng):
    return np.max(np.abs(x), axis=1)


def f5(x, rng):
    return np.sum(100.0 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (x[:, :-1] - 1.0) ** 2, axis=1)


def f6(x, rng):
    return np.sum(np.floor(x + 0.5) ** 2, axis=1)


def f7(x, rng):
    return np.sum(np.arange(1, x.shape[1] + 1) * x**4, axis=1) + rng.random(x.shape[0])


def f8(x, rng):
    return np.sum(-x * np.sin(np.sqrt(np.abs(x))), axis=1)


def f9(x, rng):
    return np.sum(x**2 - 10.0 * np.cos(2.0 * np.pi * x) + 10.0, axis=1)


def f10(x, rng):
    n = x.shape[1]
    return (
        -20.0 * np.exp(-0.2 * np.sqrt(np.sum(x**2, axis=1) / n))
        - np.exp(np.sum(np.cos(2.0 * np.pi * x), axis=1) / n)
        + 20.0
        + math.e
    )


def f11(x, rng):
    i = np.arange(1, x.shape[1] + 1)
    return np.sum(x**2, axis=1) / 4000.0 - np.prod(np.cos(x / np.sqrt(i)), axis=1) + 1.0


def f12(x, rng):
    y = 1.0 + (x + 1.0) / 4.0
    inner = np.sum((y[:, :-1] - 1.0) ** 2 * (1.0 + 10.0 * np.sin(np.pi * y[:, 1:]) ** 2), axis=1)
    body = 10.0 * np.sin(np.pi * y[:, 0]) ** 2 + inner + (y[:, -1] - 1.0) ** 2
    return np.pi / x.shape[1] * body + _penalty(x, 10.0, 100.0, 4.0)


def f13(x, rng):
    inner = np.sum((x[:, :-1] - 1.0) ** 2 * (1.0 + np.sin(3.0 * np.pi * x[:, 1:]) ** 2), axis=1)
    last = (x[:, -1] - 1.0) ** 2 * (1.0 + np.sin(2.0 * np.pi * x[:, -1]) ** 2)
    return 0.1 * (np.sin(3.0 * np.pi * x[:, 0]) ** 2 + inner + last) + _penalty(x, 5.0, 100.0, 4.0)


_FOXHOLES = np.array([np.tile([-32.0, -16.0, 0.0, 16.0, 32.0], 5), np.repeat([-32.0, -16.0, 0.0, 16.0, 32.0], 5)])


def f14(x, rng):
    sixth = np.sum((x[:, :, None] - _FOXHOLES[None, :, :]) ** 6, axis=1)
    return 1.0 / (1.0 / 500.0 + np.sum(1.0 / (np.arange(1, 26) + sixth), axis=1))


_KOWALIK_A = np.array([0.1957, 0.1947, 0.1735, 0.16, 0.0844, 0.0627, 0.0456, 0.0342, 0.0323, 0.0235, 0.0246])
_KOWALIK_B = 1.0 / np.array([0.25, 0.5, 1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0])


def f15(x, rng):
    b = _KOWALIK_B[None, :]
    model = x[:, [0]] * (b**2 + b * x[:, [1]]) / (b**2 + b * x[:, [2]] + x[:, [3]])
    return np.sum((_KOWALIK_A - model) ** 2, axis=1)


def f16(x, rng):
    a, b = x[:, 0], x[:, 1]
    return 4 * a**2 - 2.1 * a**4 + a**6 / 3 + a * b - 4 * b**2 + 4 * b**4


def f17(x, rng):
    a, b = x[:, 0], x[:, 1]
    return (b - 5.1 / (4 * np.pi**2) * a**2 + 5 / np.pi * a - 6) ** 2 + 10 * (1 - 1 / (8 * np.pi)) * np.cos(a) + 10


def f18(x, rng):
    a, b = x[:, 0], x[:, 1]
    first = 1 + (a + b + 1) ** 2 * (19 - 14 * a + 3 * a**2 - 14 * b + 6 * a * b + 3 * b**2)
    second = 30 + (2 * a - 3 * b) ** 2 * (18 - 32 * a + 12 * a**2 + 48 * b - 36 * a * b + 27 * b**2)
    return first * second


_HARTMANN_C = np.array([1.0, 1.2, 3.0, 3.2])
_HARTMANN3_A = np.array([[3.0, 10, 30], [0.1, 10, 35], [3.0, 10, 30], [0.1, 10, 35]])
_HARTMANN3_P = np.array(
    [[0.3689, 0.1170, 0.2673], [0.4699, 0.4387, 0.7470], [0.1091, 0.8732, 0.5547], [0.03815, 0.5743, 0.8828]]
)
_HARTMANN6_A = np.array(
    [[10, 3, 17, 3.5, 1.7, 8], [0.05, 10, 17, 0.1, 8, 14], [3, 3.5, 1.7, 10, 17, 8], [17, 8, 0.05, 10, 0.1, 14]]
)
_HARTMANN6_P = np.array(
    [
        [0.1312, 0.1696, 0.5569, 0.0124, 0.8283, 0.5886],
        [0.2329, 0.4135, 0.8307, 0.3736, 0.1004, 0.9991],
        [0.2348, 0.1451, 0.3522, 0.2883, 0.3047, 0.6650],
        [0.4047, 0.8828, 0.8732, 0.5743, 0.1091, 0.0381],
    ]
)


def _hartmann(x: np.ndarray, a: np.ndarray, p: np.ndarray) -> np.ndarray:
    exponent = np.sum(a[None] * (x[:, None, :] - p[None]) ** 2, axis=2)
    return -np.sum(_HARTMANN_C * np.exp(-exponent), axis=1)


def f19(x, rng):
    return _hartmann(x, _HARTMANN3_A, _HARTMANN3_P)


def f20(x, rng):
    return _hartmann(x, _HARTMANN6_A, _HARTMANN6_P)


_SHEKEL_A = np.array(
    [[4, 4, 4, 4], [1, 1, 1, 1], [8, 8, 8, 8], [6, 6, 6, 6], [3, 7, 3, 7],
     [2, 9, 2, 9], [5, 5, 3, 3], [8, 1, 8, 1], [6, 2, 6, 2], [7, 3.6, 7, 3.6]],
    dtype=float,
)  # fmt: skip
_SHEKEL_C = np.array([0.1, 0.2, 0.2, 0.4, 0.4, 0.6, 0.3, 0.7, 0.5, 0.5])


def _shekel(x: np.ndarray, m: int) -> np.ndarray:
    squared = np.sum((x[:, None, :] - _SHEKEL_A[None, :m]) ** 2, axis=2)
    return -np.sum(1.0 / (squared + _SHEKEL_C[:m]), axis=1)


def f21(x, rng):
    return _shekel(x, 5)


def f22(x, rng):
    return _shekel(x, 7)


def f23(x, rng):
    return _shekel(x, 10)


BENCHMARKS: tuple[Benchmark, ...] = (
    Benchmark("F1", "Sphere", 30, -100, 100, 0.0, (0.0,), f1),
    Benchmark("F2", "Schwefel 2.22", 30, -10, 10, 0.0, (0.0,), f2),
    Benchmark("F3", "Schwefel 1.2", 30, -100, 100, 0.0, (0.0,), f3),
    Benchmark("F4", "Schwefel 2.21", 30, -100, 100, 0.0, (0.0,), f4),
    Benchmark("F5", "Rosenbrock", 30, -30, 30, 0.0, (1.0,), f5),
    Benchmark("F6", "Step", 30, -100, 100, 0.0, (0.0,), f6),
    Benchmark("F7", "Quartic with noise", 30, -1.28, 1.28, 0.0, (0.0,), f7),
    Benchmark("F8", "Schwefel 2.26", 30, -500, 500, -418.982887272434 * 30, (420.968746,), f8),
    Benchmark("F9", "Rastrigin", 30, -5.12, 5.12, 0.0, (0.0,), f9),
    Benchmark("F10", "Ackley", 30, -32, 32, 0.0, (0.0,), f10),
    Benchmark("F11", "Griewank", 30, -600, 600, 0.0, (0.0,), f11),
    Benchmark("F12", "Penalized 1", 30, -50, 50, 0.0, (-1.0,), f12),
    Benchmark("F13", "Penalized 2", 30, -50, 50, 0.0, (1.0,), f13),
    Benchmark("F14", "Shekel's foxholes", 2, -65.536, 65.536, 0.998003837794449, (-31.97833, -31.97833), f14),
    Benchmark("F15", "Kowalik", 4, -5, 5, 3.0748598e-4, (0.192833, 0.190836, 0.123117, 0.135766), f15),
    Benchmark("F16", "Six-hump camel back", 2, -5, 5, -1.031628453489877, (0.0898420, -0.7126564), f16),
    Benchmark("F17", "Branin", 2, -5, 5, 0.397887357729739, (math.pi, 2.275), f17),
    Benchmark("F18", "Goldstein-Price", 2, -2, 2, 3.0, (0.0, -1.0), f18),
    Benchmark("F19", "Hartmann 3", 3, 0, 1, -3.86278214782076, (0.114614, 0.555649, 0.852547), f19),
    Benchmark(
        "F20", "Hartmann 6", 6, 0, 1, -3.32236801141551,
        (0.20169, 0.150011, 0.476874, 0.275332, 0.311652, 0.6573), f20,
    ),  # fmt: skip
    Benchmark("F21", "Shekel m=5", 4, 0, 10, -10.1531996790582, (4.00004, 4.00013, 4.00004, 4.00013), f21),
    Benchmark("F22", "Shekel m=7", 4, 0, 10, -10.4029405668187, (4.00057, 4.00069, 3.99949, 3.99961), f22),
    Benchmark("F23", "Shekel m=10", 4, 0, 10, -10.5364098166920, (4.00075, 4.00059, 3.99966, 3.99951), f23),
)
BY_NAME = {bench.name: bench for bench in BENCHMARKS}



PLAIN, SHIFTED, ROTATED = "plain", "shifted", "rotated"
FORMS = (PLAIN, SHIFTED, ROTATED)
FORM_SEED = 0  # root seed of every shift and rotation (module docstring)
SHIFT_SPAN = 0.8  # the new minimiser uniform in 0.8 x the box, as CEC 2005's [-80, 80] on [-100, 100]
MOVABLE = ("F1", "F2", "F3", "F4", "F5", "F6", "F7", "F9", "F10", "F11", "F12", "F13")  # forms defined


def rotation(dims: int, rng: np.random.Generator) -> np.ndarray:
    """A random rotation (uniform on the orthogonal group): Q of QR(normal), signs from R's diagonal."""
    q, r = np.linalg.qr(rng.standard_normal((dims, dims)))
    return q * np.sign(np.diag(r))


@cache
def variant(name: str, form: str) -> Benchmark:
    """F<name> in ``form`` (plain, shifted, rotated): same box and minimum value, the minimiser moved
    (and the landscape rotated about it); ValueError where the form is not defined (module docstring)."""
    bench = BY_NAME[name]
    if form == PLAIN:
        return bench
    if form not in FORMS:
        raise ValueError(f"form must be one of {', '.join(FORMS)}, not {form!r}")
    if name not in MOVABLE:
        raise ValueError(f"{name} has no {form} form (defined for {', '.join(MOVABLE)})")
    rng = np.random.default_rng([FORM_SEED, FORMS.index(form), BENCHMARKS.index(bench)])
    home = bench.at_argmin()
    moved = rng.uniform(SHIFT_SPAN * bench.low, SHIFT_SPAN * bench.high, bench.dims)
    matrix = rotation(bench.dims, rng) if form == ROTATED else np.eye(bench.dims)

    def costs(x: np.ndarray, noise: np.random.Generator) -> np.ndarray:
        return bench.costs(home + (x - moved) @ matrix.T, noise)

    return dataclasses.replace(bench, title=f"{bench.title}, {form}", argmin=tuple(moved), costs=costs, form=form)
