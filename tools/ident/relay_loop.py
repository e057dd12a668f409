"""A relay autotune's limit cycle on a linear plant, in continuous time: what a model predicts for
one cycle of Marlin's M303 or Klipper's PID_CALIBRATE at given relay levels.

The identification from relay results (tools/ident/relay_points.py) compares these predictions
with the printed cycles; it needs them smooth in the plant's parameters, so the relay here
switches at the exact instant its rule is met, found by root-finding on the plant's analytic
response (a sum of exponentials in the plant's modes), not on a sample grid: the firmware's own
reading period enters as a switching delay (``Relay.switch_delay_s``), its mean effect. The
firmware-exact run is the twin's own M303 (tools/validation/m303_compare.py ``run_twin_m303``),
which checks this one (tests/tools/ident/test_relay_loop.py).

Marlin's relay (Marlin/src/module/temperature.cpp PID_autotune): heater at the on level while
heating; off level once the reading is above the target and the half-cycle has lasted at least
5 s; on again once the reading is below the target and 5 s have passed. min is tracked over the
whole cycle (reset to the target at each switch-on), max from the switch-off (reset to the
target there), both printed at the next switch-on with Tu = t_high + t_low.

Klipper's (klippy/extras/pid_calibrate.py ControlAutoTune): max_power until the reading reaches
the target, off until it falls to TUNE_PID_DELTA below; the extreme since the previous switch is
stored at each switch (a minimum while heating, a maximum while off), Tu is the time between
peaks two apart, the swing a maximum less the minimum before it.
"""

from __future__ import annotations

import cmath
import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from firmware_port.klipper.heater import REPORT_TIME
from firmware_port.klipper.pid_calibrate import TUNE_PID_DELTA
from firmware_port.marlin.autotune import MIN_HALF_CYCLE_MS, relay_levels, update_bias
from firmware_port.marlin.constants import PID_DT_S, SOFT_PWM_MAX
from tools.ident.response import spec_lti
from twin.linear import SENSOR
from twin.plants import KELVIN, STEFAN_BOLTZMANN_W_M2_K4, Lumped, Spec, TransferFunction

MARLIN_MIN_HALF_S = MIN_HALF_CYCLE_MS / 1000.0  # each half-cycle lasts at least 5 s
# Marlin acts on the first reading after a crossing (half a reading period late on average), and
# a reading sums 16 conversions spread over the period before it (half a period old on average).
MARLIN_SWITCH_DELAY_S = float(PID_DT_S)
# Klipper acts on a report REPORT_TIME apart (half of it late on average) and applies the new pwm
# pwm_delay (REPORT_TIME by default) after the reading.
KLIPPER_SWITCH_DELAY_S = REPORT_TIME / 2 + REPORT_TIME
CYCLES = 14  # simulated cycles at most; the last one is the limit cycle's (transients decay within a few)
# A cycle whose halves repeat the last one's within this is the limit cycle: the switching instants are
# found to 1e-10 s (brentq's xtol), so the cycles after it differ by no more than that noise.
CONVERGED_S = 1e-9
GRID_POINTS = 64  # per interval at least: the grid that brackets a crossing or an extreme before refining it
GRID_STEP_S = 0.25  # and at most this far apart (a crossing and its return within one step would be missed)
MAX_GRID = 8192
FIRST_WINDOW_S = 20.0  # a crossing is looked for this far ahead first, then twice as far, ...
HORIZON_TIME_CONSTANTS = 6.0  # a half-cycle longer than this many slowest time constants never ends


class NoOscillation(ValueError):
    """The relay never switches on this plant: its levels cannot reach or leave the target."""


@dataclass(frozen=True)
class Relay:
    """A relay autotune's rules: levels (duty 0..1 of full power), where it switches, how soon."""

    target_c: float
    on_duty: float
    off_duty: float
    on_below_c: float  # switch on again below this reading (Marlin: the target; Klipper: 5 C under it)
    min_half_s: float  # each half-cycle at least this long (Marlin's 5 s; Klipper: none)
    switch_delay_s: float  # from the reading that meets the rule to the heater's new level
    peaks: str  # "marlin" (min over the cycle, max from the switch-off) or "klipper" (extremes between switches)

    @classmethod
    def marlin(cls, target_c: float, on_duty: float, off_duty: float) -> Relay:
        return cls(target_c, on_duty, off_duty, target_c, MARLIN_MIN_HALF_S, MARLIN_SWITCH_DELAY_S, "marlin")

    @classmethod
    def klipper(cls, target_c: float, max_power: float = 1.0) -> Relay:
        return cls(target_c, max_power, 0.0, target_c - TUNE_PID_DELTA, 0.0, KLIPPER_SWITCH_DELAY_S, "klipper")


class RelayCycle(NamedTuple):
    """One cycle as the firmware reports it: period, time heating and off, the extremes it prints."""

    tu_s: float
    t_high_s: float
    t_low_s: float
    min_c: float
    max_c: float

    @property
    def swing_c(self) -> float:
        return self.max_c - self.min_c


class _Modal:
    """A linear plant in its modes: dz/dt = lam z + w(u), reading = Re(c z) + offset."""

    def __init__(self, spec: Spec, ambient_c: float):
        lti = spec_lti(spec, ambient_c)
        self.delay_s = spec.delay_s if isinstance(spec, TransferFunction) else 0.0
        self.lam, v = np.linalg.eig(lti.a)
        if np.any(self.lam.real >= 0):
            raise NoOscillation("the plant is not stable: no limit cycle")
        vinv = np.linalg.inv(v)
        self.c = lti.c[SENSOR] @ v
        self.b = vinv @ lti.b
        self.e = vinv @ (lti.e @ np.array([ambient_c]))
        self.offset_c = float(lti.f[SENSOR] @ np.array([ambient_c]))
        self.slowest_s = float(1.0 / np.min(-self.lam.real))

    def steady(self, duty: float) -> np.ndarray:
        return -(self.b * duty + self.e) / self.lam

    def reading(self, z: np.ndarray) -> float:
        return float((self.c @ z).real) + self.offset_c

    def advance(self, z: np.ndarray, duty: float, dt_s: np.ndarray | float) -> np.ndarray:
        """The state(s) dt_s after z at a constant duty (rows: one per dt when dt_s is an array)."""
        zs = self.steady(duty)
        return np.exp(np.multiply.outer(dt_s, self.lam)) * (z - zs) + zs

    def readings(self, z: np.ndarray, duty: float, dt_s: np.ndarray) -> np.ndarray:
        return (self.advance(z, duty, dt_s) @ self.c).real + self.offset_c

    def reading_fn(self, z: np.ndarray, duty: float) -> Callable[[float], float]:
        """The reading dt_s after z at a constant duty, as a plain function of one time: what a root-finder
        calls many times (numpy's per-call cost would be most of it)."""
        zs = self.steady(duty)
        terms = [(complex(c * (zi - zsi)), complex(lam)) for c, zi, zsi, lam in zip(self.c, z, zs, self.lam)]
        constant = float((self.c @ zs).real) + self.offset_c

        def reading(dt_s: float) -> float:
            return constant + sum(a * cmath.exp(lam * dt_s) for a, lam in terms).real

        return reading


class _Loop:
    """The relay and the plant marching from event to event: relay switches, and the heater level
    changing a switching delay (plus the plant's dead time) after each."""

    def __init__(self, plant: _Modal, relay: Relay, z: np.ndarray):
        self.plant, self.relay = plant, relay
        self.lag_s = relay.switch_delay_s + plant.delay_s
        self.t_s = 0.0
        self.z = z
        self.duty = relay.on_duty  # the heater's level now
        self.pending: list[tuple[float, float]] = []  # (time, level): switches on their way, in time order

    def _pieces(self, start_s: float, end_s: float) -> Iterator[tuple[float, float, float, np.ndarray]]:
        """(from, to, duty, state at from) over [start_s, end_s], split where the heater's level changes."""
        t, z, duty = self.t_s, self.z, self.duty
        for at_s, level in [p for p in self.pending if p[0] < end_s] + [(end_s, duty)]:
            if at_s > start_s:
                a = max(t, start_s)
                yield a, at_s, duty, self.plant.advance(z, duty, a - t)
            z, t, duty = self.plant.advance(z, duty, at_s - t), at_s, level

    def _grid(self, length_s: float) -> np.ndarray:
        return np.linspace(0.0, length_s, int(min(max(GRID_POINTS, math.ceil(length_s / GRID_STEP_S)), MAX_GRID)))

    def first_time(self, start_s: float, above: bool, level_c: float) -> float:
        """The first time from start_s when the reading is above (or below) level_c: searched in
        windows that double from FIRST_WINDOW_S, up to the horizon."""
        import scipy.optimize  # here: a command's start-up needs no scipy
        sign = 1.0 if above else -1.0
        horizon_s = start_s + HORIZON_TIME_CONSTANTS * self.plant.slowest_s + self.lag_s
        window_s, from_s = FIRST_WINDOW_S, start_s
        while from_s < horizon_s:
            for a, b, duty, z in self._pieces(from_s, min(from_s + window_s, horizon_s)):
                dt = self._grid(b - a)
                y = sign * (self.plant.readings(z, duty, dt) - level_c)
                hit = np.flatnonzero(y > 0)
                if hit.size:
                    i = int(hit[0])
                    if i == 0:
                        return a
                    reading = self.plant.reading_fn(z, duty)
                    return a + scipy.optimize.brentq(lambda s: sign * (reading(s) - level_c),  # noqa: B023
                                                     dt[i - 1], dt[i], xtol=1e-10)
            from_s, window_s = from_s + window_s, 2.0 * window_s
        raise NoOscillation(f"the reading never gets {'above' if above else 'below'} {level_c:.4g} C")

    def extreme(self, start_s: float, end_s: float, highest: bool) -> float:
        """The highest (or lowest) reading over [start_s, end_s]."""
        import scipy.optimize  # here: a command's start-up needs no scipy
        sign = 1.0 if highest else -1.0
        best = -math.inf
        for a, b, duty, z in self._pieces(start_s, end_s):
            dt = self._grid(b - a)
            y = sign * self.plant.readings(z, duty, dt)
            i = int(np.argmax(y))
            best = max(best, float(y[i]))
            if 0 < i < len(dt) - 1:  # inside the piece: refine to the turning point
                reading = self.plant.reading_fn(z, duty)
                found = scipy.optimize.minimize_scalar(lambda s: -sign * reading(s),  # noqa: B023
                                                       bounds=(dt[i - 1], dt[i + 1]), method="bounded",
                                                       options={"xatol": 1e-9})
                best = max(best, -float(found.fun))
        return sign * best

    def switch(self, at_s: float, level: float) -> None:
        """The relay switches at at_s (no earlier than the loop's time); the heater follows after the lag."""
        while self.pending and self.pending[0][0] <= at_s:
            change_s, new = self.pending.pop(0)
            self.z, self.t_s, self.duty = self.plant.advance(self.z, self.duty, change_s - self.t_s), change_s, new
        self.z, self.t_s = self.plant.advance(self.z, self.duty, at_s - self.t_s), at_s
        self.pending.append((at_s + self.lag_s, level))


def relay_cycle(spec: Spec, ambient_c: float, relay: Relay) -> RelayCycle:
    """The limit cycle of the relay on the plant at ambient_c, as the firmware would report it (after
    CYCLES cycles from the steady state at the on level's reading of the target, or as soon as a cycle
    repeats the last within CONVERGED_S)."""
    loop, on_s = _settled(spec, ambient_c, relay)
    return _one_cycle(loop, on_s, relay.off_duty)[0]


def tangent_plant(spec: Spec, ambient_c: float, at_c: float) -> tuple[Spec, float]:
    """A radiating lumped plant linearised with its block at at_c: the tangent of its loss A (Tb - Ta) +
    sigma eps area (Tb^4 - Ta^4) there, as a linear loss k (Tb - Ta') with k the loss's slope at at_c and
    Ta' the ambient that gives the same loss at at_c; (spec, ambient_c) as given for a linear plant. A
    relay's cycle swings a few C about its target: the neglected curvature, 6 sigma eps area T^2 dT^2 / 2,
    is under a thousandth of the loss there."""
    if not isinstance(spec, Lumped) or spec.linear:
        return spec, ambient_c
    sigma_eps_a = STEFAN_BOLTZMANN_W_M2_K4 * spec.emissivity * spec.radiating_area_m2
    tb, ta = at_c + KELVIN, ambient_c + KELVIN
    loss_w = spec.ambient_xfer_w_k * (at_c - ambient_c) + sigma_eps_a * (tb ** 4 - ta ** 4)
    radiation_w_k = 4.0 * sigma_eps_a * tb ** 3
    slope_w_k = spec.ambient_xfer_w_k + radiation_w_k
    linear = dataclasses.replace(spec, ambient_xfer_w_k=slope_w_k, emissivity=0.0, radiating_area_m2=0.0,
                                 fan_ambient_xfer_w_k=spec.fan_ambient_xfer_w_k + radiation_w_k)
    return linear, at_c - loss_w / slope_w_k


def _settled(spec: Spec, ambient_c: float, relay: Relay) -> tuple[_Loop, float]:
    """The relay and the plant (a radiating one linearised at the relay's target: ``tangent_plant``) run to
    their limit cycle: the loop at a switch-on, and its time."""
    plant = _Modal(*tangent_plant(spec, ambient_c, relay.target_c))
    for duty, reach in ((relay.on_duty, "above"), (relay.off_duty, "below")):
        steady_c = plant.reading(plant.steady(duty))
        if (steady_c <= relay.target_c) if reach == "above" else (steady_c >= relay.on_below_c):
            raise NoOscillation(f"at duty {duty:.3g} the plant settles at {steady_c:.4g} C: never {reach} the "
                                f"relay's switching point")
    loop = _Loop(plant, relay, _start_state(plant, relay))
    on_s, halves = 0.0, (math.inf, math.inf)
    for _ in range(CYCLES - 1):  # to the limit cycle: only the switching instants matter on the way
        off_s = loop.first_time(on_s + relay.min_half_s, True, relay.target_c)
        loop.switch(off_s, relay.off_duty)
        next_on_s = loop.first_time(off_s + relay.min_half_s, False, relay.on_below_c)
        loop.switch(next_on_s, relay.on_duty)
        last, halves = halves, (off_s - on_s, next_on_s - off_s)
        on_s = next_on_s
        if abs(halves[0] - last[0]) + abs(halves[1] - last[1]) <= CONVERGED_S:
            break  # a cycle as long as the last, half by half: the limit cycle
    return loop, on_s


def _one_cycle(loop: _Loop, on_s: float, off_duty: float) -> tuple[RelayCycle, float]:
    """The cycle from the switch-on at on_s (the loop there) as the firmware reports it, the heater
    switched to off_duty once the rule is met; and the next switch-on's time (the loop left there, the
    switch itself to the caller: its level may change)."""
    relay = loop.relay
    off_s = loop.first_time(on_s + relay.min_half_s, True, relay.target_c)
    low_heating = loop.extreme(on_s, off_s, False)
    loop.switch(off_s, off_duty)
    next_on_s = loop.first_time(off_s + relay.min_half_s, False, relay.on_below_c)
    high = loop.extreme(off_s, next_on_s, True)
    if relay.peaks == "marlin":  # both reset to the target, min over the whole cycle
        low = min(low_heating, loop.extreme(off_s, next_on_s, False), relay.target_c)
        high = max(high, relay.target_c)
    else:
        low = low_heating
    return RelayCycle(next_on_s - on_s, off_s - on_s, next_on_s - off_s, low, high), next_on_s


class BiasCycle(NamedTuple):
    """One cycle of Marlin's relay with its bias moving: the bias and d it ran at, what it printed, and
    the bias and d Marlin's rule gives after it (printed on the same line)."""

    bias: int
    d: int
    cycle: RelayCycle
    next_bias: int
    next_d: int


def marlin_levels(bias: int, d: int) -> tuple[float, float]:
    """Marlin's relay levels (bias +- d) >> 1 on 0..SOFT_PWM_MAX, as duty."""
    on, off = relay_levels(bias, d)
    return on / SOFT_PWM_MAX, off / SOFT_PWM_MAX


def moving_bias_run(spec: Spec, ambient_c: float, target_c: float, before: tuple[int, int], start: tuple[int, int],
                    max_pow: int, cycles: int) -> list[BiasCycle]:
    """Marlin's M303 relay on the plant with its bias moving as Marlin moves it: the limit cycle at the
    levels of ``before`` (bias, d: the cycle that ran before), then ``cycles`` cycles from a switch-on,
    the first at the levels of ``start``, each next at the bias and d Marlin's rule gives from the
    cycle's t_high and t_low in whole ms (firmware_port/marlin/autotune.py ``update_bias``, clamped
    within max_pow)."""
    loop, on_s = _settled(spec, ambient_c, Relay.marlin(target_c, *marlin_levels(*before)))
    bias, d = start
    out = []
    for _ in range(cycles):
        on_duty, off_duty = marlin_levels(bias, d)
        loop.switch(on_s, on_duty)
        cycle, on_s = _one_cycle(loop, on_s, off_duty)
        next_bias, next_d = update_bias(bias, d, round(cycle.t_high_s * 1000), round(cycle.t_low_s * 1000), max_pow)
        out.append(BiasCycle(bias, d, cycle, next_bias, next_d))
        bias, d = next_bias, next_d
    return out


def _start_state(plant: _Modal, relay: Relay) -> np.ndarray:
    """The plant settled at the reading the relay switches on at, heater just turned on: the
    steady state at the duty that holds that reading (the mean of the levels if none does)."""
    low, high = (plant.reading(plant.steady(d)) for d in (relay.off_duty, relay.on_duty))
    frac = (relay.on_below_c - low) / (high - low) if high != low else 0.5
    return plant.steady(relay.off_duty + min(max(frac, 0.0), 1.0) * (relay.on_duty - relay.off_duty))
