"""An M303 capture against the twin's own M303: fit a plant on the capture's relay trace, run
Marlin's autotune (firmware_port/marlin/autotune.py) on it at the capture's target and cycles, and
compare the relay period Tu, the swing max - min and the gains, twin against log.

The plant: three_node, sopdt or fopdt, whichever has the lowest AIC (the relay period and swing are
set by the lag between heater and sensor: a third node or a dead time; the two-node model has too
little of it), fitted from the first reconstructed switch on, ambient from --ambient or the capture's idle heater (tools/ident/relay_trace.py),
switch instants reconstructed between the 2 s status lines, power assumed as twin-fit does.

The sensor's noise: near a bed's 60 C target one 10-bit step is about 0.2 C, a fifth of a bed's
relay swing; a noiseless twin sees the target crossed only a whole step late, up to 4 s at a bed's
0.05 C/s, which lengthens its period by a fifth. A real board's conversions scatter and Marlin sums
OVERSAMPLENR of them, resolving the crossing finer than a step. So the twin's ADC gets the noise
that gives its readings the capture's own: estimated from the fit's residuals (second differences,
which the relay's slow curvature hardly touches), times sqrt(OVERSAMPLENR) (the sum averages
independent conversions) and the chain's counts per kelvin at the target, less the floor's own share. The run is seeded.

Compared: the mean of the log's printed Tu and max - min over its cycles that print Tu, against
the mean over the twin's cycles that print Tu (at least MIN_TWIN_CYCLES cycles are run, more than
a capture prints: its noisy periods are averaged over six or more; the twin starts from ambient).
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmware_port.marlin.autotune import STR_CLASSIC_PID
from firmware_port.marlin.board import BED_CHANNEL, HOTEND_CHANNEL
from firmware_port.marlin.constants import OVERSAMPLENR
from tools.ident.fit import best_fit, reading_noise_c
from tools.ident.result import FitResult
from tools.ident.segments import NotFittable, Segment, log_segments
from tools.logs import M303Cycle, M303Log, load_log, parse_m303
from tools.ident.relay_trace import ambient_hint_c
from twin.engine import BOOT_S, Twin
from twin.plants import BED_POWER_W, MPC_HEATER_POWER_W, Plant, make_plant
from twin.sensor import SensorChain

MODELS = ("three_node", "sopdt", "fopdt")  # a third node or a dead time; chosen by AIC
DEFAULT_CYCLES = 5  # Marlin's M303 C default
CYCLE_RE_KEY = {"extruder": "T", "heater_bed": "B"}
MAX_RUN_S = 3600.0  # a twin M303 that has not finished by then will not (Marlin's own timeout is 20 min a cycle)
GOAL_TU_REL = 0.10  # issue 14: the period within 10 %
GOAL_SWING_REL = 0.25  # and the swing within 25 %
MIN_FULL_CYCLES = 2
MIN_TWIN_CYCLES = 8  # the twin's M303 cycles at least: Marlin prints Tu from the third, so six or more
NOISE_SEED = 0  # the twin's ADC noise draws
QUANTISATION_LSB2 = 1.0 / 12.0  # the variance of a dithered floor: uniform over one count
CLASSIC_PID = STR_CLASSIC_PID.strip()  # judged where the capture prints at least this many cycles


class NoRelay(ValueError):
    """A capture without a relay trace to fit or without printed cycles to compare."""


@dataclass(frozen=True)
class RelayStats:
    """Mean Tu and swing over some relay cycles, and the last cycle's gains."""

    cycles: int
    tu_s: float
    swing_c: float
    gains: tuple[float, float, float] | None


@dataclass(frozen=True)
class M303Comparison:
    file: str
    heater: str
    target_c: float
    ncycles: int
    ambient_c: float
    segment: Segment
    fit: FitResult
    noise_c: float  # the capture's reading noise (standard deviation)
    noise_lsb: float  # the twin's ADC noise per conversion that reproduces it
    log: RelayStats
    twin: RelayStats

    @property
    def tu_rel(self) -> float:
        return (self.twin.tu_s - self.log.tu_s) / self.log.tu_s

    @property
    def swing_rel(self) -> float:
        return (self.twin.swing_c - self.log.swing_c) / self.log.swing_c

    @property
    def judged(self) -> bool:
        return self.log.cycles >= MIN_FULL_CYCLES

    @property
    def passed(self) -> bool:
        return abs(self.tu_rel) <= GOAL_TU_REL and abs(self.swing_rel) <= GOAL_SWING_REL


def relay_stats(cycles: list[M303Cycle], last: int | None = None) -> RelayStats:
    """Mean Tu and max - min over the cycles that print Tu (the last ``last`` of them)."""
    full = [c for c in cycles if c.tu_s and c.min_c is not None and c.max_c is not None]
    if last is not None:
        full = full[-last:]
    if not full:
        raise NoRelay("no relay cycle prints its Tu")
    gains = next(((c.kp, c.ki, c.kd) for c in reversed(full) if None not in (c.kp, c.ki, c.kd)), None)
    return RelayStats(len(full), float(np.mean([c.tu_s for c in full])),
                      float(np.mean([c.max_c - c.min_c for c in full])), gains)  # type: ignore[arg-type, operator]


def _relay_segment(segments: list[Segment]) -> Segment:
    """The segment with the most reconstructed switches (the relay, not the heat-up before it)."""
    switches = [0 if s.observed is None else int(np.sum(~s.observed)) for s in segments]
    if not max(switches):
        raise NoRelay("no status run in the capture switches the relay")
    return segments[int(np.argmax(switches))]


def twin_noise_lsb(noise_c: float, temp_c: float) -> float:
    """The ADC noise per conversion (LSB) that gives the twin's readings a standard deviation of
    noise_c at temp_c. Marlin reads the sum of OVERSAMPLENR conversions, which averages
    independent scatter by sqrt(OVERSAMPLENR), through the chain's counts per kelvin there; each
    conversion's floor adds 1/12 LSB^2 of its own once the noise dithers it (Widrow's model of
    quantisation noise), so the noise asked for is what remains. 0 where the floor alone scatters
    as much."""
    variance_lsb2 = OVERSAMPLENR * (noise_c * SensorChain().lsb_per_c(temp_c)) ** 2 - QUANTISATION_LSB2
    return math.sqrt(max(variance_lsb2, 0.0))


def run_twin_m303(fit: FitResult, heater: str, ambient_c: float, target_c: float, ncycles: int,
                  version: str = "2.1", noise_lsb: float = 0.0) -> M303Log:
    """The twin's M303 (Marlin ``version``) on the fitted plant from ambient, its ADC conversions
    scattered by noise_lsb (seeded): its console output, read back as a capture."""
    plant = Plant(fit.model, fit.spec(), ambient_c, ambient_c)
    other = make_plant("bed" if heater == "extruder" else "hotend", ambient_c=ambient_c)
    plants = [plant, other] if heater == "extruder" else [other, plant]
    twin = Twin(plants, noise_lsb=noise_lsb, seed=NOISE_SEED)
    twin.set_ambient(ambient_c)
    twin.boot(BOOT_S)
    channel = HOTEND_CHANNEL if heater == "extruder" else BED_CHANNEL
    twin.board.start_autotune(channel, int(round(target_c)), ncycles, version=version)
    while twin.board.autotune is not None and twin.time_s < MAX_RUN_S:
        twin.run_until(twin.time_s + 10.0)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "twin_m303.txt"
        path.write_text(twin.console.text)
        return parse_m303(path)


def m303_check(path: str | Path, heater: str | None = None, ambient_c: float | None = None) -> M303Comparison:
    """Fit the capture's relay trace, run the twin's M303 at its target, compare Tu and swing."""
    path = Path(path)
    log = load_log(path)
    if not isinstance(log, M303Log):
        raise NoRelay("not an M303 capture")
    try:
        heater, segments = log_segments(log, heater)
    except NotFittable as error:
        raise NoRelay(str(error)) from None
    seg = _relay_segment(segments)
    ambient = ambient_hint_c(log) if ambient_c is None else ambient_c
    power_w = BED_POWER_W if heater == "heater_bed" else MPC_HEATER_POWER_W
    fit = best_fit(MODELS, seg, ambient, power_w)
    logged = relay_stats([c for c in log.cycles if c.heater == CYCLE_RE_KEY[heater]])
    command_cycles = [int(c.split("C")[1].split()[0]) for _, c in log.commands if " C" in c]
    ncycles = max(command_cycles[-1] if command_cycles else DEFAULT_CYCLES, logged.cycles + 2, MIN_TWIN_CYCLES)
    # A bed tuned by the "Classic PID" rule: Marlin 1.1 or Prusa's firmware, not 2.x's "No overshoot"
    version = "1.1" if heater == "heater_bed" and log.rule == CLASSIC_PID else "2.1"
    noise_c = reading_noise_c(fit.residuals_c)
    noise_lsb = twin_noise_lsb(noise_c, seg.target_c)
    twin_log = run_twin_m303(fit, heater, ambient, seg.target_c, ncycles, version, noise_lsb)
    twin = relay_stats(twin_log.cycles)
    return M303Comparison(path.name, heater, seg.target_c, ncycles, ambient, seg, fit, noise_c, noise_lsb, logged, twin)


M303_HEADER = ("| log | heater | target (C) | ambient (C) | model (by AIC), fit RMSE (C) | reading noise (C) / twin ADC noise (LSB) "
               "| cycles log / twin | Tu log / twin (s) | error "
               "| swing max-min log / twin (C) | error | gains Kp/Ki/Kd log | gains Kp/Ki/Kd twin | Tu <= 10 %, swing <= 25 % |\n"
               "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
M303_COLUMNS = 14


def _gains(g: tuple[float, float, float] | None) -> str:
    return "n/a" if g is None else " / ".join(f"{x:.2f}" for x in g)


def m303_row(r: M303Comparison) -> str:
    verdict = ("pass" if r.passed else "**miss**") if r.judged else f"not judged: {r.log.cycles} cycle printed"
    return (f"| `{r.file}` | {r.heater} | {r.target_c:g} | {r.ambient_c:.1f} | {r.fit.model}, {r.fit.rmse_c:.2f} | "
            f"{r.noise_c:.3f} / {r.noise_lsb:.1f} | {r.log.cycles} / {r.twin.cycles} | {r.log.tu_s:.2f} / {r.twin.tu_s:.2f} | {100 * r.tu_rel:+.1f} % | "
            f"{r.log.swing_c:.2f} / {r.twin.swing_c:.2f} | {100 * r.swing_rel:+.1f} % | {_gains(r.log.gains)} | "
            f"{_gains(r.twin.gains)} | {verdict} |")


UNDETERMINED_REL = 1.0  # a standard error beyond the value itself: the trace does not determine it


def _spread(error: float, value: float) -> str:
    """A relative standard error; beyond 100 % only that (its digits depend on the BLAS kernel)."""
    rel = abs(error / value)
    return "> 100 % (undetermined)" if rel > UNDETERMINED_REL else f"{100 * rel:.1f} %"


def spread_note(r: M303Comparison) -> str:
    """How well the trace determines the fitted lags: each parameter's standard error relative to it."""
    parts = [f"{name} {_spread(r.fit.std_errors[name], value)}" for name, value in r.fit.params.items()
             if name not in ("initial_c", "ambient_c") and value and np.isfinite(r.fit.std_errors[name])]
    seen = int(np.sum(r.segment.observed)) if r.segment.observed is not None else len(r.segment.t_s)
    return (f"`{r.file}` ({r.fit.model} on {seen} compared status lines): relative standard errors "
            + ", ".join(parts))
