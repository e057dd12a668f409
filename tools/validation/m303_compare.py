"""An M303 capture against the twin's own M303, in sample and out of sample.

The plant: fitted to the capture (tools/ident/log_fit.py: its printed relay cycles, each a
measured point of the loop, and its 2 s status trace where it has one), on all its printed cycles
(in-sample) or on the first ``fit_cycles`` of them and the trace up to the last of those, the later
cycles left to predict (out-of-sample); three_node, sopdt or fopdt, whichever has the lowest AIC
on the fitted data. Or an outside plant: a preset (twin/plants.py) or a plant fitted to another
log, against which every cycle is out-of-sample.

The twin runs Marlin's autotune (firmware_port/marlin/autotune.py; Marlin 1.1 for a bed tuned by
the "Classic PID" rule, as Prusa's firmware does, else 2.1) on the plant at the capture's target,
from ambient, for MIN_TWIN_CYCLES cycles or more, and its mean Tu and swing (max - min) over the
cycles that print Tu are compared with the mean over each group of the capture's printed cycles:
the fitted ones (in-sample) and the later ones (out-of-sample). Where the capture has a status
trace, the fitted plant also replays the logged relay levels over the whole trace, from the fit's
start: its error over the fitted lines is in-sample, over the later lines out-of-sample.

The twin's sensor: a fit to relay results holds their reading noise already (it reproduces the
printed cycles with a noiseless relay), so the twin's ADC gets only the dither DITHER_LSB that
lets Marlin's sum of 16 conversions resolve a crossing finer than one step (Widrow: Gaussian
dither of half a step leaves a mean-reading bias under 1 % of a step); a noiseless ADC would see
a bed's 60 C crossed a whole 0.2 C step late. A plant fitted to a trace alone gets the trace's
own noise (its residuals' second differences), through Marlin's sum of 16 conversions and the
divider's slope at the target (``twin_noise_lsb``). The run is seeded.

The relay floor: Marlin's half-cycles last at least 5 s, so Tu cannot fall below RELAY_FLOOR_S.
Where the log's or the twin's Tu lies within FLOOR_MARGIN_REL of it, the period says more about
the 5 s rule than about the plant: the row is flagged and the swing alone decides it.

Goals: Tu within 10 % and swing within 25 % (for a plant fitted to a trace); a plant
fitted to the printed results alone, 15 % and 30 %.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from firmware_port.marlin.autotune import STR_CLASSIC_PID
from firmware_port.marlin.board import BED_CHANNEL, HOTEND_CHANNEL
from firmware_port.marlin.constants import OVERSAMPLENR
from tools.ident.fit import reading_noise_c
from tools.ident.log_fit import LogFit, LogFitOptions, fit_log
from tools.ident.relay_loop import MARLIN_MIN_HALF_S
from tools.ident.relay_points import cycles_target_c, relay_heater
from tools.ident.relay_trace import ambient_hint_c
from tools.ident.response import zoh_response
from tools.ident.result import aic
from tools.ident.segments import NotFittable, Segment, default_segment, log_segments
from tools.logs import M303Cycle, M303Log, load_log, parse_m303
from twin.engine import BOOT_S, Twin
from twin.plants import SPECS, Plant, Spec, make_plant
from twin.sensor import SensorChain

MODELS = ("three_node", "sopdt", "fopdt")  # a third node or a dead time; chosen by AIC
DEFAULT_CYCLES = 5  # Marlin's M303 C default
CYCLE_RE_KEY = {"extruder": "T", "heater_bed": "B"}
MAX_RUN_S = 3600.0  # a twin M303 that has not finished by then will not (Marlin's own timeout is 20 min a cycle)
RUN_STEP_S = 10.0  # the twin runs this much virtual time between progress reports
GOALS = {"trace": (0.10, 0.25), "results": (0.15, 0.30)}  # (Tu, swing): fitted to a trace; to the result lines alone
GOAL_TU_REL, GOAL_SWING_REL = GOALS["trace"]
MIN_TWIN_CYCLES = 8  # the twin's M303 cycles at least: Marlin prints Tu from the third, so six or more
NOISE_SEED = 0  # the twin's ADC noise draws
DITHER_LSB = 0.5  # per conversion: the smallest scatter that lets a 16-conversion sum resolve a crossing
QUANTISATION_LSB2 = 1.0 / 12.0  # the variance of a dithered floor: uniform over one count
CLASSIC_PID = STR_CLASSIC_PID.strip()  # a bed tuned by this rule: Marlin 1.1 or Prusa's firmware
RELAY_FLOOR_S = 2.0 * MARLIN_MIN_HALF_S  # two 5 s half-cycles at least
FLOOR_MARGIN_REL = 0.10  # a Tu within 10 % of the floor (under 11 s) is set by the 5 s rule, not the plant
IN, OUT = "in-sample", "out-of-sample"


class NoRelay(ValueError):
    """A capture without printed cycles to compare, or a plant that cannot be had for it."""


@dataclass(frozen=True)
class RelayStats:
    """Mean Tu and swing over some relay cycles, and the last cycle's gains."""

    cycles: int
    tu_s: float
    swing_c: float
    gains: tuple[float, float, float] | None


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


def on_floor(tu_s: float) -> bool:
    """A Tu within FLOOR_MARGIN_REL of Marlin's 10 s floor."""
    return tu_s <= RELAY_FLOOR_S * (1.0 + FLOOR_MARGIN_REL)


@dataclass(frozen=True)
class CycleRow:
    """The twin against a group of the capture's printed cycles (1-based, first..last)."""

    sample: str  # IN or OUT
    first: int
    last: int
    log: RelayStats
    twin: RelayStats
    goals: tuple[float, float]  # Tu, swing

    @property
    def tu_rel(self) -> float:
        return (self.twin.tu_s - self.log.tu_s) / self.log.tu_s

    @property
    def swing_rel(self) -> float:
        return (self.twin.swing_c - self.log.swing_c) / self.log.swing_c

    @property
    def floor(self) -> bool:
        """The Tu of the log or of the twin sits on the relay floor: swing decides."""
        return on_floor(self.log.tu_s) or on_floor(self.twin.tu_s)

    @property
    def passed(self) -> bool:
        tu_ok = self.floor or abs(self.tu_rel) <= self.goals[0]
        return tu_ok and abs(self.swing_rel) <= self.goals[1]


@dataclass(frozen=True)
class TraceRow:
    """The plant replaying the logged relay levels over part of the status trace."""

    sample: str
    first_line: int
    last_line: int
    readings: int
    rmse_c: float
    max_error_c: float


@dataclass(frozen=True)
class M303Comparison:
    file: str
    heater: str
    target_c: float
    ambient_c: float
    plant: str  # what the plant is: "fopdt by AIC, fitted on ...", "preset hotend", ...
    fitted: LogFit | None  # None for an outside plant
    spec: Spec
    noise_lsb: float  # the twin's ADC noise per conversion
    noise_note: str
    version: str
    ncycles: int
    twin: RelayStats
    rows: list[CycleRow]
    trace_rows: list[TraceRow] = field(default_factory=list)
    trace: tuple | None = None  # (t_s, logged, plant, duty) for a plot
    capture: M303Log | None = None  # the capture read

    def out_of_sample(self) -> list[CycleRow]:
        return [r for r in self.rows if r.sample == OUT]


def twin_noise_lsb(noise_c: float, temp_c: float) -> float:
    """The ADC noise per conversion (LSB) that gives the twin's readings a standard deviation of
    noise_c at temp_c. Marlin reads the sum of OVERSAMPLENR conversions, which averages
    independent scatter by sqrt(OVERSAMPLENR), through the chain's counts per kelvin there; each
    conversion's floor adds 1/12 LSB^2 of its own once the noise dithers it (Widrow's model of
    quantisation noise), so the noise asked for is what remains. 0 where the floor alone scatters
    as much."""
    variance_lsb2 = OVERSAMPLENR * (noise_c * SensorChain().lsb_per_c(temp_c)) ** 2 - QUANTISATION_LSB2
    return math.sqrt(max(variance_lsb2, 0.0))


def run_twin_m303(name: str, spec: Spec, heater: str, ambient_c: float, target_c: float, ncycles: int,
                  version: str = "2.1", noise_lsb: float = 0.0,
                  on_progress: Callable[[float], None] | None = None, start_c: float | None = None) -> M303Log:
    """The twin's M303 (Marlin ``version``) on the plant from ambient (or every node at start_c), its ADC
    conversions scattered by noise_lsb (seeded): its console output, read back as a capture. on_progress
    gets the virtual seconds run so far, every RUN_STEP_S."""
    plant = Plant(name, spec, ambient_c, ambient_c if start_c is None else start_c)
    other = make_plant("bed" if heater == "extruder" else "hotend", ambient_c=ambient_c)
    plants = [plant, other] if heater == "extruder" else [other, plant]
    twin = Twin(plants, noise_lsb=noise_lsb, seed=NOISE_SEED)
    twin.set_ambient(ambient_c)
    twin.boot(BOOT_S)
    channel = HOTEND_CHANNEL if heater == "extruder" else BED_CHANNEL
    twin.board.start_autotune(channel, int(round(target_c)), ncycles, version=version)
    while twin.board.autotune is not None and twin.time_s < MAX_RUN_S:
        twin.run_until(twin.time_s + RUN_STEP_S)
        if on_progress is not None:
            on_progress(twin.time_s)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "twin_m303.txt"
        path.write_text(twin.console.text)
        return parse_m303(path)


# --- the plant ---------------------------------------------------------------------------------


def best_log_fit(log: M303Log, heater: str | None, ambient_c: float | None, fit_cycles: int | None,
                 on_evaluation: Callable[[], None] | None = None) -> LogFit:
    """MODELS fitted to the capture (its first fit_cycles printed cycles), the lowest AIC kept."""
    fits = [fit_log(log, LogFitOptions(model=m, heater=heater, ambient_c=ambient_c, fit_cycles=fit_cycles,
                                       on_evaluation=on_evaluation)) for m in MODELS]
    return min(fits, key=lambda f: aic(f.result))


def outside_plant(name: str, on_evaluation: Callable[[], None] | None = None) -> tuple[str, Spec, str]:
    """(model name, spec, description) of a preset, or of the plant twin-fit fits to the log at that path."""
    if name in SPECS:
        return name, SPECS[name], f"preset {name} (twin/plants.py)"
    path = Path(name)
    if not path.is_file():
        raise NoRelay(f"--plant {name}: neither a preset ({', '.join(SPECS)}) nor a log file")
    fitted = fit_log(load_log(path), LogFitOptions(on_evaluation=on_evaluation))
    if reason := fitted.degenerate:
        raise NoRelay(f"--plant {name}: degenerate fit: {reason}")
    r = fitted.result
    return r.model, r.spec(), f"{r.model} fitted to {path.name} ({r.evidence})"


def _twin_noise(fitted: LogFit | None, target_c: float) -> tuple[float, str]:
    """The twin's ADC noise and why: the trace's own for a trace-only fit, else the dither."""
    if fitted is None:
        return DITHER_LSB, "dither only: an outside plant"
    if fitted.result.evidence == "trace":
        noise_c = reading_noise_c(fitted.trace_residuals_c())
        return twin_noise_lsb(noise_c, target_c), f"the trace's reading noise {noise_c:.3f} C"
    return DITHER_LSB, "dither only: the relay results' noise is in the fitted plant"


# --- the comparison ----------------------------------------------------------------------------


def _cycle_rows(printed: list[M303Cycle], fit_cycles: int | None, outside: bool, twin: RelayStats,
                goals: tuple[float, float]) -> list[CycleRow]:
    """The twin against the fitted cycles (in-sample) and the later ones (out-of-sample)."""
    n = len(printed)
    if outside:
        groups = [(OUT, 1, n)]
    elif fit_cycles is None or fit_cycles >= n:
        groups = [(IN, 1, n)]
    else:
        groups = [(IN, 1, fit_cycles), (OUT, fit_cycles + 1, n)]
    return [CycleRow(sample, a, b, relay_stats(printed[a - 1 : b]), twin, goals) for sample, a, b in groups]


def _trace_rows(segment: Segment, sim_c: np.ndarray, sample_until_line: int | None) -> list[TraceRow]:
    """Error over the trace's lines up to sample_until_line (in-sample; all of them if None) and after
    (out-of-sample); every line out-of-sample for an outside plant (sample_until_line 0)."""
    seen = np.ones(len(segment.t_s), bool) if segment.observed is None else segment.observed
    lines = segment.line_nos if segment.line_nos is not None else np.zeros(len(segment.t_s), int)
    last = int(lines.max()) if sample_until_line is None else sample_until_line
    rows = []
    for sample, part in ((IN, lines <= last), (OUT, lines > last)):
        keep = part & seen
        if keep.any():
            err = sim_c[keep] - segment.temp_c[keep]
            rows.append(TraceRow(sample, int(lines[keep].min()), int(lines[keep].max()), int(keep.sum()),
                                 float(np.sqrt(np.mean(err ** 2))), float(np.max(np.abs(err)))))
    return rows


def _replay(fitted: LogFit | None, outside: tuple[str, Spec] | None, log: M303Log, heater: str, ambient_c: float,
            fit_cycles: int | None) -> tuple[list[TraceRow], tuple | None]:
    """The plant replaying the capture's relay trace with its logged levels: a fit from its own start,
    split at the last fitted line; an outside plant from the first reading, all out-of-sample."""
    if fitted is not None:
        if fitted.chosen is None or fitted.segment is None:
            return [], None
        whole = fitted.segments[fitted.chosen]
        sim = fitted.result.simulate(whole.t_s, whole.duty)
        last = fitted.points[-1].line_no if fit_cycles and fitted.points else None
        return _trace_rows(whole, sim, last), (whole.t_s, whole.temp_c, sim, whole.duty)
    try:
        _, segments = log_segments(log, heater)
    except NotFittable:
        return [], None
    whole = segments[default_segment(segments)]
    assert outside is not None
    sim = zoh_response(Plant(*outside, ambient_c, float(whole.temp_c[0])), whole.t_s, whole.duty)
    return _trace_rows(whole, sim, 0), (whole.t_s, whole.temp_c, sim, whole.duty)


def m303_check(path: str | Path, heater: str | None = None, ambient_c: float | None = None,
               fit_cycles: int | None = None, plant: str | None = None,
               on_evaluation: Callable[[], None] | None = None,
               on_progress: Callable[[float], None] | None = None) -> M303Comparison:
    """The twin's M303 on a plant for the capture against its printed cycles (module docstring)."""
    path = Path(path)
    log = load_log(path)
    if not isinstance(log, M303Log):
        raise NoRelay("not an M303 capture")
    try:
        fitted = None if plant is not None else best_log_fit(log, heater, ambient_c, fit_cycles, on_evaluation)
    except NotFittable as error:
        raise NoRelay(str(error)) from None
    if fitted is not None:
        heater, target_c, ambient = fitted.heater, fitted.result.anchor_c, fitted.result.ambient_c
        name, spec = fitted.result.model, fitted.result.spec()
        what = "in-sample on all" if fit_cycles is None else f"on the first {fit_cycles} of"
        description = (f"{name} by lowest AIC of {', '.join(MODELS)}, fitted {what} the printed cycles"
                       f" ({fitted.result.evidence})")
    else:
        assert plant is not None
        name, spec, description = outside_plant(plant, on_evaluation)
        heater = heater or relay_heater(log)[0]
        target_c, ambient = cycles_target_c(log, CYCLE_RE_KEY[heater]), ambient_hint_c(log) if ambient_c is None else ambient_c
    assert target_c is not None
    printed = printed_cycles(log, heater)
    ncycles, version = twin_settings(log, heater, printed)
    noise_lsb, noise_note = _twin_noise(fitted, target_c)
    twin_log = run_twin_m303(name, spec, heater, ambient, target_c, ncycles, version, noise_lsb, on_progress)
    twin = relay_stats(twin_log.cycles)
    has_trace = fitted is not None and "trace" in fitted.result.evidence
    goals = GOALS["trace" if has_trace or fitted is None else "results"]
    rows = _cycle_rows(printed, fit_cycles, fitted is None, twin, goals)
    trace_rows, trace = _replay(fitted, None if fitted else (name, spec), log, heater, ambient, fit_cycles)
    return M303Comparison(path.name, heater, target_c, ambient, description, fitted, spec, noise_lsb, noise_note,
                          version, ncycles, twin, rows, trace_rows, trace, log)


def printed_cycles(log: M303Log, heater: str) -> list[M303Cycle]:
    """The heater's printed cycles with Tu, min and max; NoRelay where there are none."""
    printed = [c for c in log.cycles_of(CYCLE_RE_KEY[heater]) if c.tu_s and c.min_c is not None and c.max_c is not None]
    if not printed:
        raise NoRelay("no printed cycle with Tu, min and max to compare")
    return printed


def twin_settings(log: M303Log, heater: str, printed: list[M303Cycle]) -> tuple[int, str]:
    """The twin's M303 for a capture: its cycles (the command's C, else Marlin's default, and at least two
    more than printed and MIN_TWIN_CYCLES) and Marlin version (1.1 for a bed tuned by the Classic rule)."""
    command_cycles = [int(c.split("C")[1].split()[0]) for _, c in log.commands if " C" in c]
    ncycles = max(command_cycles[-1] if command_cycles else DEFAULT_CYCLES, len(printed) + 2, MIN_TWIN_CYCLES)
    return ncycles, "1.1" if heater == "heater_bed" and log.rule == CLASSIC_PID else "2.1"


def replay_fit(log: M303Log, fitted: LogFit, on_progress: Callable[[float], None] | None = None) -> CycleRow:
    """The twin's M303 on a plant fitted to the capture, against all the printed cycles (in-sample), under
    the goals of what the fit saw: how a plant the capture allows must replay it. The twin starts where
    the capture does: at its status trace's first reading, or, for result lines alone (which do not
    show the start; some runs start pre-warmed), with the plant at the relay's target."""
    heater, result = fitted.heater, fitted.result
    assert result.anchor_c is not None  # a fit to relay points knows its relay's target
    printed = printed_cycles(log, heater)
    ncycles, version = twin_settings(log, heater, printed)
    noise_lsb, _ = _twin_noise(fitted, result.anchor_c)
    start_c = float(fitted.segment.temp_c[0]) if fitted.segment is not None else result.anchor_c
    twin_log = run_twin_m303(result.model, result.spec(), heater, result.ambient_c, result.anchor_c, ncycles,
                             version, noise_lsb, on_progress, start_c)
    goals = GOALS["trace" if "trace" in result.evidence else "results"]
    return CycleRow(IN, 1, len(printed), relay_stats(printed), relay_stats(twin_log.cycles), goals)


# --- rows as table cells -----------------------------------------------------------------------

CYCLE_COLUMNS = ("sample", "printed cycles", "Tu log / twin (s)", "Tu error", "swing log / twin (C)", "swing error",
                 "goal Tu / swing", "verdict")
TRACE_COLUMNS = ("sample", "trace lines", "readings", "RMSE (C)", "max error (C)")


def verdict(row: CycleRow) -> str:
    """pass / miss for an out-of-sample row (Tu on the relay floor: the swing decides); in-sample rows are listed only."""
    if row.sample == IN:
        return "listed, not scored"
    floor = " (Tu on the 10 s relay floor: swing decides)" if row.floor else ""
    return ("pass" if row.passed else "**miss**") + floor


def cycle_cells(row: CycleRow) -> list[str]:
    flag = " (floor)" if row.floor else ""
    return [row.sample, f"{row.first}..{row.last}" if row.last > row.first else str(row.first),
            f"{row.log.tu_s:.2f} / {row.twin.tu_s:.2f}", f"{100 * row.tu_rel:+.1f} %{flag}",
            f"{row.log.swing_c:.2f} / {row.twin.swing_c:.2f}", f"{100 * row.swing_rel:+.1f} %",
            f"{100 * row.goals[0]:g} % / {100 * row.goals[1]:g} %", verdict(row)]


def trace_cells(row: TraceRow) -> list[str]:
    return [row.sample, f"{row.first_line}..{row.last_line}", str(row.readings), f"{row.rmse_c:.2f}",
            f"{row.max_error_c:.2f}"]


def heading(r: M303Comparison) -> list[str]:
    """What was compared: the capture, the plant, the twin's run."""
    return [f"`{r.file}`: {r.heater}, target {r.target_c:g} C, ambient {r.ambient_c:.1f} C",
            f"plant: {r.plant}",
            f"twin: Marlin {r.version} M303, {r.ncycles} cycles from ambient, ADC noise {r.noise_lsb:.2f} LSB per "
            f"conversion ({r.noise_note}); {r.twin.cycles} cycles print Tu"]
