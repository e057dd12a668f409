"""The ultimate point (Ku, Tu) of any linear model: from its frequency response, and from an ideal
relay experiment on it.

Ku is the proportional gain (heater duty per degC) at which the loop oscillates steadily, Tu the
period. From the model: the phase crossover, arg G(jw_u) = -180 deg, Ku = 1 / |G(jw_u)|,
Tu = 2 pi / w_u, for any model (lags, leads, complex poles, dead time), not only a FOPDT; this
supersedes tools/ident/fit.py ``ultimate_point``. From a relay (Astrom and Hagglund 1984,
"Automatic tuning of simple regulators with specifications on phase and amplitude margins",
Automatica 20(5):645-651): a relay of amplitude d makes the loop oscillate with amplitude a near
the crossover, and the describing function gives Ku ~ 4 d / (pi a).

    point = ultimate_point(model_of(SPECS["seed001_fopdt"]))
    relay = relay_experiment(model_of(SPECS["seed001_fopdt"]))

``python -m tools.tuning.ultimate`` prints both for every plant preset.
"""

from __future__ import annotations

import argparse
import math
from typing import NamedTuple

import numpy as np

from tools.entry import OneLineParser, run_cli
from tools.tuning.models import LinearModel, model_of
from twin.plants import SPECS, Lumped

GRID_DECADES_BELOW = 4.0  # the phase search starts this far below the model's slowest corner
GRID_DECADES_ABOVE = 4.0  # and ends this far above its fastest corner (or 1/dead time)
GRID_POINTS_PER_DECADE = 200
RELAY_STEPS_PER_PERIOD = 4000  # relay simulation step: at most the crossover period / this
RELAY_CYCLES = 30  # relay cycles simulated; the last RELAY_MEASURED are measured
RELAY_MEASURED = 5
RELAY_MAX_STEPS = 2_000_000
HARMONICS = 50  # odd harmonics summed in the describing function's error bound
# The relay's output wave lies between a triangle (a lag-dominant plant integrates the square wave)
# and a square (a pure dead time passes it): the fundamental's amplitude is 8/pi^2 .. 4/pi of the
# peak a, so 4 d / (pi a) is 8/pi^2 .. 4/pi of 1/|G| at the oscillation's frequency.
WAVE_FACTORS = (8.0 / math.pi**2, 4.0 / math.pi)


class UltimatePoint(NamedTuple):
    """ku: heater duty per degC (x 255 for Marlin's M303 Ku); tu_s: the period; w_rad_s = 2 pi / tu_s."""

    ku: float
    tu_s: float

    @property
    def w_rad_s(self) -> float:
        return 2.0 * math.pi / self.tu_s


def _root_phase(w: np.ndarray, root: complex) -> np.ndarray:
    """arg(jw - root), continuous in w >= 0 (a right-half-plane root is measured from the other side)."""
    if root.real > 0:
        return np.angle(root - 1j * w) + math.pi
    return np.angle(1j * w - root)


def phase_rad(model: LinearModel, w_rad_s: np.ndarray) -> np.ndarray:
    """arg G(jw), unwrapped from 0 at w = 0 (a positive static gain): the rational part from its
    poles and zeros, root by root, minus w delay_s."""
    if model.static_gain <= 0:
        raise ValueError("the model needs a positive static gain (more heat, higher temperature)")
    w = np.asarray(w_rad_s, dtype=float)
    num, den = model.polynomials()
    total = sum((_root_phase(w, z) for z in np.roots(num)), np.zeros_like(w))
    total -= sum((_root_phase(w, p) for p in np.roots(den)), np.zeros_like(w))
    at_zero = sum(_root_phase(np.zeros(1), z)[0] for z in np.roots(num)) - sum(
        _root_phase(np.zeros(1), p)[0] for p in np.roots(den))
    return total - at_zero - w * model.delay_s


def _corners(model: LinearModel) -> tuple[float, float]:
    num, den = model.polynomials()
    rates = np.abs(np.r_[np.roots(num), np.roots(den)])
    rates = rates[rates > 0]
    slow = float(rates.min())
    fast = max(float(rates.max()), 1.0 / model.delay_s if model.delay_s else 0.0)
    return slow, fast


def ultimate_point(model: LinearModel) -> UltimatePoint:
    """The first phase crossover (lowest frequency where arg G = -180 deg), solved by brentq
    between the grid points around it. For heater models (lags, a dead time) the phase falls
    monotonically, so this is the only crossover and Ku the smallest gain that destabilises a P loop.
    ValueError when the phase never reaches -180 deg (a first or second order lag without dead
    time: stable at any proportional gain; add the control loop's delay with ``model.delayed``)."""
    slow, fast = _corners(model)
    w = np.logspace(math.log10(slow) - GRID_DECADES_BELOW, math.log10(fast) + GRID_DECADES_ABOVE,
                    int((GRID_DECADES_BELOW + GRID_DECADES_ABOVE + math.log10(fast / slow)) * GRID_POINTS_PER_DECADE))
    margin = phase_rad(model, w) + math.pi
    below = np.flatnonzero(margin < 0)
    if not below.size:
        raise ValueError("no ultimate point: the phase never reaches -180 deg (the loop is stable at any "
                         "proportional gain); add the control loop's delay")
    i = int(below[0])
    import scipy.optimize
    w_u = scipy.optimize.brentq(lambda x: float(phase_rad(model, np.array([x]))[0]) + math.pi, w[i - 1], w[i],
                                xtol=1e-14, rtol=1e-12)
    return UltimatePoint(float(1.0 / abs(model.response(np.array([w_u]))[0])), 2.0 * math.pi / w_u)


class RelayResult(NamedTuple):
    """An ideal relay run: Ku = 4 d / (pi a), its period, the amplitude a (degC) and the trace."""

    point: UltimatePoint
    amplitude_c: float
    t_s: np.ndarray
    temp_c: np.ndarray  # deviation from the set point's equilibrium
    duty: np.ndarray  # the relay's output, +-d


def _relay_step_s(model: LinearModel) -> float:
    """The largest step that divides the dead time and is at most Tu / RELAY_STEPS_PER_PERIOD."""
    if not model.delay_s:
        raise ValueError("an ideal relay on a model without dead time chatters; add the control loop's delay")
    longest_s = ultimate_point(model).tu_s / RELAY_STEPS_PER_PERIOD
    return model.delay_s / math.ceil(model.delay_s / longest_s)


def relay_experiment(model: LinearModel, amplitude: float = 1.0, hysteresis_c: float = 0.0,
                     step_s: float | None = None, cycles: int = RELAY_CYCLES) -> RelayResult:
    """An ideal relay u = +-amplitude on the error e = -y (set point at the model's equilibrium,
    deviations only), switching to +amplitude when e > hysteresis_c and to -amplitude when
    e < -hysteresis_c; the model stepped exactly (zero-order hold) at step_s, its dead time as
    whole steps (step_s defaults to Tu / 4000 or less, dividing the dead time). Ku and Tu from the last 5 of ``cycles``
    cycles: Tu the mean time between switch-ons, a half the output's peak-to-peak.
    With hysteresis the relay finds the point where arg G = -180 deg + asin(hysteresis / a)."""
    if amplitude <= 0 or hysteresis_c < 0 or cycles <= RELAY_MEASURED:
        raise ValueError("relay: amplitude must be > 0, hysteresis_c >= 0, cycles > 5")
    h = _relay_step_s(model) if step_s is None else float(step_s)
    delay_steps = round(model.delay_s / h)
    n = len(model.b)
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n], aug[:n, n] = model.a, model.b
    import scipy.linalg
    disc = scipy.linalg.expm(aug * h)
    phi, gam = disc[:n, :n], disc[:n, n]
    # one step at a time; the dead time is a ring buffer of the last delay_steps outputs
    buffer = np.full(delay_steps, amplitude)
    x = np.zeros(n)
    u = amplitude
    ons: list[int] = []
    ys, us = [], []
    for k in range(RELAY_MAX_STEPS):
        y = float(model.c @ x)
        e = -y
        if u < 0 and e > hysteresis_c:
            u = amplitude
            ons.append(k)
            if len(ons) > cycles:
                break
        elif u > 0 and e < -hysteresis_c:
            u = -amplitude
        ys.append(y)
        us.append(u)
        applied = buffer[k % delay_steps] if delay_steps else u
        if delay_steps:
            buffer[k % delay_steps] = u
        x = phi @ x + gam * applied
    else:
        raise ValueError(f"the relay did not complete {cycles} cycles in {RELAY_MAX_STEPS} steps")
    start = ons[-RELAY_MEASURED - 1]
    last = np.array(ys[start:])
    half_swing_c = 0.5 * float(last.max() - last.min())
    tu_s = h * (ons[-1] - start) / RELAY_MEASURED
    point = UltimatePoint(4.0 * amplitude / (math.pi * half_swing_c), tu_s)
    return RelayResult(point, half_swing_c, h * np.arange(len(ys)), np.array(ys), np.array(us))


def harmonic_bound(model: LinearModel, point: UltimatePoint, harmonics: int = HARMONICS) -> float:
    """How far a relay's Ku may lie from the exact crossover's by the describing function's own
    approximation: the square wave's odd harmonics k = 3, 5, ... pass through G with gain
    |G(jk w_u)| / k relative to the fundamental's |G(jw_u)|, so the output's peak differs from the
    fundamental's amplitude by at most sum_k |G(jk w_u)| / (k |G(jw_u)|) of it (the error bound of
    the describing-function method, Astrom and Hagglund, PID Controllers: Theory, Design, and
    Tuning, 1995, section 2.7)."""
    k = np.arange(3, 2 * harmonics + 2, 2)
    g = np.abs(model.response(np.r_[point.w_rad_s, k * point.w_rad_s]))
    return float(np.sum(g[1:] / k) / g[0])


class RelayTolerance(NamedTuple):
    """Where a relay's (Ku, Tu) may lie around the exact crossover by the describing function's error."""

    ku_low: float
    ku_high: float
    tu_low_s: float
    tu_high_s: float

    def holds(self, point: UltimatePoint) -> bool:
        return self.ku_low <= point.ku <= self.ku_high and self.tu_low_s <= point.tu_s <= self.tu_high_s


def relay_tolerance(model: LinearModel, point: UltimatePoint) -> RelayTolerance:
    """The describing function's error, from the model: the relay's exact oscillation satisfies
    sum over odd k of Im G(jk w) / k = 0 (Tsypkin's condition), so the fundamental's phase misses
    -180 deg by at most asin(b), b = ``harmonic_bound``; the frequencies within that phase give the
    Tu range, and 1/|G| over them times the wave factors 8/pi^2 .. 4/pi give the Ku range."""
    miss_rad = math.asin(min(1.0, harmonic_bound(model, point)))
    w = point.w_rad_s * np.logspace(-1.0, 1.0, 4001)
    near = np.abs(phase_rad(model, w) + math.pi) <= miss_rad
    runs = np.flatnonzero(np.diff(near.astype(int)))  # the run of frequencies around w_u
    centre = int(np.argmin(np.abs(w - point.w_rad_s)))
    low = int(runs[runs < centre].max()) + 1 if np.any(runs < centre) else 0
    high = int(runs[runs >= centre].min()) if np.any(runs >= centre) else len(w) - 1
    gain = 1.0 / np.abs(model.response(w[low : high + 1]))
    return RelayTolerance(WAVE_FACTORS[0] * float(gain.min()), WAVE_FACTORS[1] * float(gain.max()),
                          2.0 * math.pi / float(w[high]), 2.0 * math.pi / float(w[low]))


# Seed 000's plants have no dead time of their own: the firmware's control period adds one.
CONTROL_PERIOD_S = 0.16384  # Marlin's PID_dT on the ATmega328 (firmware_port/marlin/constants.py)


def build_parser() -> OneLineParser:
    return OneLineParser(prog="python -m tools.tuning.ultimate",
                         description="Every plant preset's ultimate point from its model beside an ideal relay's on it.")


def print_points(_args: argparse.Namespace) -> int:
    """Print every plant preset's ultimate point from its model beside an ideal relay's on it."""
    print(f"{'preset':<18} {'extra delay':>11} {'Ku model':>10} {'Tu model':>9} {'Ku relay':>10} {'Tu relay':>9} "
          f"{'dKu %':>6} {'dTu %':>6}  Ku range (DF)        Tu range (DF)")
    for name, spec in SPECS.items():
        if isinstance(spec, Lumped) and not spec.linear:
            continue
        model = model_of(spec)
        extra_s = 0.0 if model.delay_s else CONTROL_PERIOD_S
        model = model.delayed(extra_s)
        point, relay = ultimate_point(model), relay_experiment(model).point
        tol = relay_tolerance(model, point)
        print(f"{name:<18} {extra_s:>10.5f}s {point.ku:>10.5g} {point.tu_s:>8.4g}s {relay.ku:>10.5g} "
              f"{relay.tu_s:>8.4g}s {100 * (relay.ku / point.ku - 1):>+6.1f} {100 * (relay.tu_s / point.tu_s - 1):>+6.1f}"
              f"  {tol.ku_low:.4g}..{tol.ku_high:.4g}  {tol.tu_low_s:.4g}..{tol.tu_high_s:.4g} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), print_points, argv)


if __name__ == "__main__":
    raise SystemExit(main())
