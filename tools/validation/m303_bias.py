"""Marlin's M303 relay with its bias moving, predicted cycle by cycle from a plant fitted to the first cycles.

Marlin moves the relay's bias and d at every switch-on from the cycle's high and low times (bias += d
(t_high - t_low) / (t_high + t_low), clamped; firmware_port/marlin/autotune.py ``update_bias``) and prints
them with the cycle's min and max, so each printed cycle ran at the levels of the bias line before it.
A plant fitted to the first K printed cycles (tools/ident/log_fit.py, the lowest AIC of
tools/validation/m303_compare.py MODELS) predicts each later cycle two ways
(tools/ident/relay_loop.py ``moving_bias_run``):

- one step: cycle j from the model's relay settled at the levels cycle j-1 ran at, then switched to
  the bias and d Marlin printed after cycle j-1 (the bias Marlin's rule gave there): the bias lines
  are the relay's inputs, only the fitted cycles' results enter the plant;
- free run: from the bias and d printed after the K-th fitted cycle, the model's relay runs on by
  itself, its bias moving by Marlin's rule from its own t_high and t_low: the logged bias lines after
  cycle K are predicted too.

The mean Tu and swing of the predicted cycles are scored against the log's; an in-sample row (fitted on
every printed cycle, each predicted one step) is listed apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_port.marlin.constants import MAX_BED_POWER, PID_MAX
from tools.ident.log_fit import BED, LogFit
from tools.ident.relay_loop import BiasCycle, NoOscillation, moving_bias_run, relay_cycle
from tools.ident.relay_points import HEATER_KEYS
from tools.logs import M303Cycle, M303Log, load_log
from tools.validation.m303_compare import NoRelay, best_log_fit


@dataclass(frozen=True)
class Predicted:
    """Printed cycles against the model's: their mean Tu (s) and swing (C), log and twin."""

    cycles: tuple[int, ...]  # 1-based numbers of the printed cycles (those with Tu) predicted
    tu_log_s: float
    tu_twin_s: float
    swing_log_c: float
    swing_twin_c: float
    bias_log: tuple[int, ...]  # the bias printed after each predicted cycle, by the log and by the model
    bias_twin: tuple[int, ...]

    @property
    def tu_error(self) -> float:
        return self.tu_twin_s / self.tu_log_s - 1.0

    @property
    def swing_error(self) -> float:
        return self.swing_twin_c / self.swing_log_c - 1.0


@dataclass(frozen=True)
class BiasCheck:
    """One capture's moving-bias prediction: the fit, how many printed cycles it saw, the two predictions."""

    name: str
    heater: str
    fitted: LogFit
    fit_cycles: int
    printed: int
    one_step: Predicted
    free_run: Predicted | None  # None in sample (no cycle after the fitted ones)


def bias_lines(log: M303Log, heater: str) -> list[M303Cycle]:
    """The heater's bias lines, in order: each printed cycle, with or without Tu."""
    return [c for c in log.cycles_of(HEATER_KEYS[heater]) if c.bias is not None and c.d is not None]


def _scored(lines: list[M303Cycle]) -> list[int]:
    """Indices (into the bias lines) of the printed cycles with Tu, min and max, after a bias line."""
    return [i for i, c in enumerate(lines) if i and c.tu_s and c.min_c is not None and c.max_c is not None]


def _levels(c: M303Cycle) -> tuple[int, int]:
    assert c.bias is not None and c.d is not None
    return c.bias, c.d


def _predicted(numbers: list[int], logged: list[M303Cycle], twin: list[BiasCycle]) -> Predicted:
    scored = [(c, t) for c, t in zip(logged, twin) if c.tu_s and c.min_c is not None and c.max_c is not None]
    return Predicted(tuple(numbers), float(np.mean([c.tu_s for c, _ in scored])),
                     float(np.mean([t.cycle.tu_s for _, t in scored])),
                     float(np.mean([c.max_c - c.min_c for c, _ in scored])),  # type: ignore[operator]
                     float(np.mean([t.cycle.swing_c for _, t in scored])),
                     tuple(c.bias for c in logged), tuple(t.next_bias for t in twin))  # type: ignore[misc]


def bias_check(path: str | Path, heater: str | None = None, fit_cycles: int | None = None) -> BiasCheck:
    """Fit the first ``fit_cycles`` printed cycles (default half of them; all of them: in sample) and predict
    the later ones with the bias moving (module docstring). NoRelay where the capture has no printed cycle
    after a bias line."""
    path = Path(path)
    log = load_log(path)
    if not isinstance(log, M303Log):
        raise NoRelay(f"{path.name}: not an M303 capture")
    first = best_log_fit(log, heater, None, None)
    heater = first.heater
    lines = bias_lines(log, heater)
    scored = _scored(lines)
    if not scored:
        raise NoRelay(f"{path.name}: no printed cycle with Tu, min and max after a bias line")
    n = len([c for c in lines if c.tu_s and c.min_c is not None and c.max_c is not None])
    k = (n // 2 if n >= 2 else n) if fit_cycles is None else fit_cycles
    fitted = first if k == n else best_log_fit(log, heater, None, k)
    result, target_c = fitted.result, fitted.target_c
    assert target_c is not None
    max_pow = MAX_BED_POWER if heater == BED else PID_MAX
    first_predicted = scored[k - n] if k < n else scored[0]
    later = [i for i in scored if i >= first_predicted]
    numbers = [n - len(scored) + scored.index(i) + 1 for i in later]
    one = [moving_bias_run(result.spec(), result.ambient_c, target_c, _levels(lines[max(i - 2, 0)]),
                           _levels(lines[i - 1]), max_pow, 1)[0] for i in later]
    one_step = _predicted(numbers, [lines[i] for i in later], one)
    free_run = None
    if k < n:
        start = first_predicted - 1
        run = moving_bias_run(result.spec(), result.ambient_c, target_c, _levels(lines[max(start - 1, 0)]),
                              _levels(lines[start]), max_pow, len(lines) - first_predicted)
        free_run = _predicted(numbers, lines[first_predicted:], run)
    return BiasCheck(path.name, heater, fitted, k, n, one_step, free_run)


def own_relay_note(fitted: LogFit, goals: tuple[float, float]) -> str:
    """Where a fitted plant's M303 replay misses a capture, whether the fit itself misses the printed cycles:
    the plant's own relay cycle at each fitted cycle's logged levels (the bias line before it), mean Tu and
    swing against the printed ones' (within the replay's goals, or not); "" without relay points."""
    points, result = fitted.points, fitted.result
    if not points:
        return ""
    try:
        own = [relay_cycle(result.spec(), result.ambient_c, p.relay) for p in points]
    except NoOscillation as exc:
        return f"the plant's own relay at the printed cycles' levels does not oscillate: {exc}"
    tu_log, tu_own = np.mean([p.tu_s for p in points]), np.mean([c.tu_s for c in own])
    swing_log, swing_own = np.mean([p.swing_c for p in points]), np.mean([c.swing_c for c in own])
    within = abs(tu_own / tu_log - 1.0) <= goals[0] and abs(swing_own / swing_log - 1.0) <= goals[1]
    why = ("so the fit reproduces them at their levels: the twin's M303, its bias moving from the run's start, "
           "cycles at other levels than the capture's" if within
           else "so the fit misses the printed cycles themselves: no value of its parameters meets them and the rest "
                "of the capture at once")
    return (f"the plant's own relay at the printed cycles' logged levels: Tu {tu_own:.4g} s, swing {swing_own:.3g} C "
            f"(log {tu_log:.4g} s, {swing_log:.3g} C), {why}")

