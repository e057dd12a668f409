"""One linear view of every plant the project has: heater duty (0..1) to sensor temperature.

Lumped plants (twin/plants.py ``Lumped``, under given conditions), the seeds' transfer functions
with their dead time (``TransferFunction``) and fitted models (tools/ident/fit.py
``FitResult.spec()``) all become a ``LinearModel``: the sensor row of their state-space model plus
a dead time. From it: the frequency response G(jw) with the dead time, the static gain, the exact
step response and a FOPDT equivalent for the FOPDT rules.

    model = model_of(SPECS["seed003_third"])
    g = model.response(np.array([0.01, 0.1]))      # complex, degC per unit duty
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from tools.ident.fopdt import Fopdt, two_point_fopdt
from twin.linear import SENSOR, Lti, TickModel
from twin.plants import Conditions, Lumped, Plant, Spec

STEP_POINTS = 20000  # grid of the step response for the FOPDT equivalent (as tools/ident/fit.py)
NEGLIGIBLE = 1e-12  # a numerator coefficient this small against the largest is rounding: dropped
SETTLE_TIME_CONSTANTS = 8.0  # the step response runs this many slowest time constants


@dataclass(frozen=True)
class LinearModel:
    """x' = A x + b u, y = c x, the input delayed by delay_s; u is the heater duty 0..1, y degC of rise."""

    a: np.ndarray  # (n, n) 1/s
    b: np.ndarray  # (n,)
    c: np.ndarray  # (n,) the sensor row
    delay_s: float = 0.0

    def __post_init__(self) -> None:
        if not np.all(np.linalg.eigvals(self.a).real < 0):
            raise ValueError("the model must be stable (every pole in the left half plane)")
        if self.delay_s < 0:
            raise ValueError(f"delay_s={self.delay_s!r}: must be >= 0")

    def delayed(self, extra_s: float) -> LinearModel:
        """The same model with extra_s more dead time (e.g. the control loop's own delay)."""
        return dataclasses.replace(self, delay_s=self.delay_s + extra_s)

    def polynomials(self) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator of the rational part, highest power first."""
        import scipy.signal
        num, den = scipy.signal.ss2tf(self.a, self.b[:, None], self.c[None, :], np.zeros((1, 1)))
        num = num[0]
        # ss2tf leaves rounding residue where the numerator's leading coefficients are zero
        leading = np.flatnonzero(np.abs(num) > NEGLIGIBLE * np.abs(num).max())[0]
        return num[leading:], den

    @property
    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.a)

    @property
    def static_gain(self) -> float:
        """degC of rise per unit duty at steady state: -c A^-1 b."""
        return float(-self.c @ np.linalg.solve(self.a, self.b))

    def response(self, w_rad_s: np.ndarray) -> np.ndarray:
        """G(jw) = c (jw I - A)^-1 b e^(-jw delay) at each w (rad/s)."""
        w = np.atleast_1d(np.asarray(w_rad_s, dtype=float))
        eye = np.eye(len(self.b))
        rational = np.array([self.c @ np.linalg.solve(1j * wk * eye - self.a, self.b) for wk in w])
        return rational * np.exp(-1j * w * self.delay_s)

    @property
    def slowest_time_constant_s(self) -> float:
        return float(1.0 / np.min(np.abs(self.poles.real)))

    def step_response(self, step_s: float, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """(t_s, degC) of the unit step at t = 0, exact (zero-order hold) at t = delay_s + k step_s."""
        lti = Lti(self.a, self.b, np.zeros((len(self.b), 1)), np.vstack((self.c, self.c)), np.zeros((2, 1)))
        y = TickModel(lti, step_s).u_steps(n_steps) @ self.c
        return self.delay_s + step_s * np.arange(n_steps + 1), y

    def fopdt(self) -> Fopdt:
        """FOPDT equivalent: tools/ident/fit.py's two-point method on the exact step response
        (the same construction as ``identify.fopdt_equivalent``, for any model). Its dead time is
        at least the model's own: a lead (seed 003's zero) speeds the early rise so much that the
        two-point method reads a negative dead time, but nothing moves before the dead time."""
        step_s = SETTLE_TIME_CONSTANTS * self.slowest_time_constant_s / STEP_POINTS
        t_s, y = self.step_response(step_s, STEP_POINTS)
        k, tau, delay = two_point_fopdt(np.r_[0.0, t_s], np.r_[0.0, y], 1.0, final_c=self.static_gain)
        return Fopdt(k, tau, max(delay, self.delay_s))


def model_of(plant: Spec | Plant, conditions: Conditions | None = None) -> LinearModel:
    """The duty-to-sensor model of a plant spec or Plant. Lumped plants use ``conditions``
    (default: part fan off, no flow; a radiating plant needs its linearisation point there)."""
    spec = plant.spec if isinstance(plant, Plant) else plant
    if isinstance(spec, Lumped):
        if conditions is None:
            if not spec.linear:
                raise ValueError("a radiating plant needs conditions (its linearisation temperature)")
            conditions = Conditions(0.0, 0.0)
        lti = spec.lti(conditions)
        delay_s = 0.0
    else:
        lti = spec.lti()
        delay_s = spec.delay_s
    return LinearModel(np.asarray(lti.a, float), np.asarray(lti.b, float), np.asarray(lti.c[SENSOR], float), delay_s)
