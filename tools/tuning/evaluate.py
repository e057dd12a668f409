"""Evaluate candidate controllers in the loop: parameters (N, d) of the problem's controller -> runs.

A ``Problem`` is a plant (a preset's or a fitted spec), a ``TuneScenario``, a loop and a
controller family (firmware_port/params.py ``ParamSpace``: its parameters and a factory; by
default Marlin's fixed-point PID, whose parameters are Kp, Ki, Kd on the 0..255 scale):

- ``marlin`` (default): the controller on Marlin's board (ADC, soft PWM, thermal protection) in
  lockstep with the plant. Candidates the batch twin runs (twin/batch.py ``BatchTwin.accepts``: the
  fixed-point PID, bang-bang, the fuzzy PI and the fuzzy-PID) run as lanes of one batch, on any plant
  (a radiating loss needs numba's compiled lanes), others one ``Twin`` each.
- ``klipper``: Klipper's host PID (twin/klipper_twin.py) as lanes of a ``KlipperBatch`` (with numba;
  else one ``KlipperTwin`` per candidate), PID families only.
- ``kalico``: the Klipper loop with Kalico's heater (firmware_port/kalico: its PWM rules; its PID on the
  same lanes, its PID_CALIBRATE the autotune), and Kalico's MPC (firmware_port/firmwares.py
  ``kalico_mpc_space``, MPC_CALIBRATE its autotune) on one ``KlipperTwin`` per candidate.
- ``ideal``: the papers' loop: a continuous PID, Kp + Ki/s + Kd s/(s/N + 1) with Simulink's
  default filter N = 100 1/s, on the plant's linear model, no saturation, no quantisation, the
  dead time exact; stepped with the plant's exact zero-order hold at ``IDEAL_DT_S`` (backward
  Euler for the controller), all candidates at once (PID families only).

The scenario heats from ambient to the target, then disturbs the loop: on a lumped heater a part
fan kick, the filament flow starting, then an ambient change; on a transfer-function plant (no
fan or flow in its model) a load step at the plant input of ``LOAD_FRACTION`` of full scale, as
seed 002 (OCALO-PID, Zhou et al. 2024) section 4.3 does with its 0.1 step at 520 s.

Candidates are split into chunks of ``CHUNK_LANES``; with a dask.distributed ``Client`` the
chunks run on its workers, else in this process: the same chunks either way, so the same numbers.
``simulate(..., record=False)`` asks a batch to keep no trace and to stream the heater objective's
inputs instead (tools/tuning/objectives.py ``needs_trace``): what an optimiser's evaluations do.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from contextlib import contextmanager
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from firmware_port.kalico import CONTROL_MPC, KalicoHeaterConfig, MpcConfig
from firmware_port.klipper import CommandError, HeaterConfig
from firmware_port.lane_law import law_for
from twin import batch_kernel
from firmware_port.marlin.board import HOTEND_CHANNEL
from firmware_port.marlin.mpc_autotune import MpcAutotune
from firmware_port.firmwares import KALICO_MPC, param_space
from firmware_port.marlin.pid import pid_space
from firmware_port.params import ParamSpace
from tools.ident.fopdt import CONTROL_DELAY_S
from tools.tuning.defaults import LOOPS
from tools.tuning.ensemble import Ensemble, Member
from tools.tuning.gains import COUNTS_PER_DUTY, Gains
from tools.tuning.models import model_of
from tools.tuning.objectives import Run, needs_trace, score_spec
from tools.tuning.rules import tune
from tools.validation.compare import HeaterInfo, make_setup
from twin.batch import BatchTwin
from twin.engine import Twin
from twin.klipper_batch import KlipperBatch
from twin.engine_protocol import Stack
from twin.klipper_twin import HeaterSetup, KlipperTwin, extruder_setup
from twin.linear import SENSOR, Lti
from twin.plants import SPECS, Lumped, Plant, Spec, TransferFunction
from twin.scenario import Event
from twin.streaming import ScoreTotals

KLIPPER_FAMILY = ("klipper", "kalico")  # Klipper's host loop, with Klipper's heater or Kalico's
CHUNK_LANES = 32  # candidates per batch: one dask task
AMBIENT_C = 25.0
HEATUP_FACTOR = 3.0  # heat-up phase = 3 x the open-loop time to the target at full power
MIN_PHASE_S = 100.0
PHASE_ROUND_S = 10.0
FAN_KICK = 1.0  # part fan to full
FLOW_MM_S = 5.0  # 1.75 mm filament at 5 mm/s: about 12 mm^3/s, a brisk print
AMBIENT_STEP_C = 10.0  # an enclosure warming up
LOAD_FRACTION = 0.1  # seed 002's 0.1 step, of the input's full scale
IDEAL_DT_S = 0.05
IDEAL_FILTER_PER_S = 100.0  # Simulink PID block's default filter coefficient N
M303_CYCLES = 8
AUTOTUNE_TIMEOUT_S = 2 * 20 * 60.0  # twice Marlin's MAX_CYCLE_TIME_PID_AUTOTUNE (20 min)
AUTOTUNE_POLL_S = 10.0
KLIPPER_MAX_TEMP_C = 300.0  # above any tuning target, so only a real runaway trips
# a Klipper section's own options that Kalico reads as Klipper does; the PWM rules are each firmware's
KALICO_CARRIED = ("name", "min_temp_c", "max_temp_c", "pid_kp", "pid_ki", "pid_kd", "max_delta_c", "max_power",
                  "smooth_time_s", "pwm_delay_s")
OUT_OF_RANGE_COST = 1e9  # a candidate the firmware cannot take


def klipper_family(loop: str) -> bool:
    """Whether the loop is Klipper's host loop (``klipper``, or ``kalico`` with Kalico's heater)."""
    return loop in KLIPPER_FAMILY


@dataclass(frozen=True)
class TuneScenario:
    """Heat from ambient_c to target_c at t = 0, the events after (fan, flow, ambient, load), end at duration_s."""

    target_c: float
    duration_s: float
    ambient_c: float
    events: tuple[Event, ...]

    @property
    def disturbances_s(self) -> tuple[float, ...]:
        return tuple(event.at_s for event in self.events)

    def at_ambient(self, ambient_c: float) -> TuneScenario:
        """The same scenario in another room: the heat-up from ambient_c, an ambient step by as much."""
        shift = ambient_c - self.ambient_c
        events = tuple(replace(e, value=_value(e) + shift) if e.kind == "ambient" else e for e in self.events)
        return replace(self, ambient_c=ambient_c, events=events)


@dataclass(frozen=True)
class Problem:
    """What a tune evaluates on: a named plant spec, a scenario, a loop, a controller family."""

    name: str
    spec: Spec
    scenario: TuneScenario
    loop: str = "marlin"
    controller: ParamSpace = field(default_factory=pid_space)
    ensemble: Ensemble | None = None  # None: this plant only, with the sensor below
    noise_lsb: float = 0.0  # the ADC's noise (an ensemble's members set their own)
    seed: int = 0  # the noise's seed
    engine: str = "fast"  # the scalar twins' engine (twin/engine.py ENGINES): "reference" for a proof
    klipper: HeaterInfo | None = None  # the Klipper loop's heater settings (a log's); None: Klipper's example
    # the heater_power a host's MPC states (Kalico's): a printer's setting, so every member keeps the nominal's;
    # 0: this plant's input at full duty
    heater_power_w: float = 0.0

    def __post_init__(self) -> None:
        if not self.heater_power_w:
            object.__setattr__(self, "heater_power_w", self.input_full_scale)
        if self.loop not in LOOPS:
            raise ValueError(f"unknown loop {self.loop!r}; choose one of: {', '.join(LOOPS)}")
        kalico_mpc = self.controller.name == KALICO_MPC
        if kalico_mpc and self.loop != "kalico":
            raise ValueError(f"controller {KALICO_MPC} is Kalico's MPC: it runs on the kalico loop only")
        if self.loop != "marlin" and not (self.controller.pid or kalico_mpc):
            raise ValueError(f"the {self.loop} loop runs a PID{' or Kalico MPC' if self.loop == 'kalico' else ''}: "
                             f"controller {self.controller.name} runs on the marlin loop only")

    @property
    def input_full_scale(self) -> float:
        """The plant input at duty 1: W for a lumped heater, the paper's unit for a transfer function."""
        return self.spec.input_full_scale

    def members(self) -> list[Problem]:
        """One problem per ensemble member (its plant, noise and seed); [self] without an ensemble."""
        if self.ensemble is None:
            return [self]
        return [self._member(m, m.seed) for m in self.ensemble.members]

    def runs(self) -> list[Problem]:
        """One problem per run of a search: every member on each of its seeds; [self] without an ensemble."""
        if self.ensemble is None:
            return [self]
        return [self._member(m, seed) for m, seed in self.ensemble.runs()]

    def _member(self, m: Member, seed: int) -> Problem:
        return replace(self, spec=m.spec(self.spec), noise_lsb=m.noise_lsb, seed=seed, ensemble=None,
                       scenario=self.scenario if m.ambient_c is None else self.scenario.at_ambient(m.ambient_c))

    def reduce(self, costs: np.ndarray) -> np.ndarray:
        """Costs of every run's lanes (runs x N, member-major) -> one cost per candidate (N,)."""
        return np.ravel(costs) if self.ensemble is None else self.ensemble.reduce(costs)

    @property
    def batched(self) -> bool:
        """Whether candidates run as lanes of one batch (else one twin each, as always on the reference
        engine). Without numba, only the numpy lanes' cases: the Marlin loop on a linear plant (with or
        without dead time). Kalico's MPC has no lanes."""
        if self.loop == "ideal":
            return True
        if self.engine == "reference":
            return False
        if not batch_kernel.compiled() and (klipper_family(self.loop) or not self.spec.linear):
            return False
        if klipper_family(self.loop):
            return self.controller.pid
        controller = self.controller.make(self.controller.defaults)
        if law_for(controller) is None:
            _no_lane_law(type(controller))
        return BatchTwin.accepts(controller)

    def plant_gains(self, params: np.ndarray) -> np.ndarray | None:
        """A PID family's gains (N, 3) on the 0..255 scale -> the plant's input units per degC (W/C for a
        heater); None for other controllers."""
        if not self.controller.pid:
            return None
        return np.asarray(params, float) / COUNTS_PER_DUTY * self.input_full_scale


@functools.cache
def _no_lane_law(family: type) -> None:
    """Say once per family that its candidates run one scalar twin each (``Problem.batched``)."""
    warnings.warn(f"controller {family.__name__} declares no lane law (firmware_port/lane_law.py): each candidate "
                  "runs on a scalar twin of its own, hundreds of times slower than on the batch", stacklevel=3)


# -- the plant and its scenario ---------------------------------------------------------------------
class LoadedPlant(Plant):
    """A plant with a load at its input: d = [ambient, load (fraction of full scale)]. A transfer function
    has no fan or flow terms, so a load is its disturbance; in an ensemble that mixes transfer functions
    with lumped heaters the lumped ones take the same load (heat drawn where the heater's enters)."""

    def __init__(self, preset: str, spec: Spec, ambient_c: float):
        loaded = _LOADED[type(spec)](**{f.name: getattr(spec, f.name) for f in dataclasses.fields(spec)})
        super().__init__(preset, loaded, ambient_c)
        self.load = 0.0
        self.d = np.array([ambient_c, 0.0])

    def set_inputs(self, fan: float, flow_mm_s: float, ambient_c: float) -> None:
        """As Plant's, keeping the load."""
        self.fan, self.flow_mm_s = float(fan), float(flow_mm_s)
        self.d = np.array([ambient_c, self.load])
        self.relinearise()

    def set_load(self, load: float) -> None:
        self.load = float(load)
        self.d = np.array([self.ambient_c, self.load])


class _Load:
    """A spec's model with the load as a second disturbance, added to u."""

    def lti(self, key=None) -> Lti:
        base = super().lti(key)  # type: ignore[misc]
        e = np.column_stack((base.e[:, 0], base.b))
        return Lti(base.a, base.b, e, base.c, np.column_stack((base.f[:, 0], np.zeros(2))))


@dataclass(frozen=True)
class _LoadedTransferFunction(_Load, TransferFunction):
    pass


@dataclass(frozen=True)
class _LoadedLumped(_Load, Lumped):
    pass


_LOADED: dict[type, type] = {TransferFunction: _LoadedTransferFunction, Lumped: _LoadedLumped}


def make_problem_plant(problem: Problem) -> Plant:
    """A fresh plant at the scenario's ambient, every node there; a LoadedPlant where the scenario has loads."""
    if any(event.kind == "load" for event in problem.scenario.events):
        return LoadedPlant(problem.name, problem.spec, problem.scenario.ambient_c)
    return Plant(problem.name, problem.spec, problem.scenario.ambient_c)


def _sensor_step(lti: Lti) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop sensor rise at full power: times and values (to 10 time constants of the slowest pole)."""
    slowest_s = 1.0 / np.min(np.abs(np.linalg.eigvals(lti.a).real))
    t = np.linspace(0.0, 10.0 * slowest_s, 4001)
    import scipy.signal  # here: the tuning layer's import stays light (twin-tune --help)
    system = scipy.signal.StateSpace(lti.a, lti.b[:, None], lti.c[SENSOR][None, :], np.zeros((1, 1)))
    _, y = scipy.signal.step(system, T=t)
    return t, y


def full_power_time_s(spec: Spec, ambient_c: float, target_c: float) -> float:
    """The open-loop time from ambient to target_c at full power (dead time included).

    ValueError when full power cannot hold the target."""
    lti = spec.rest_lti(ambient_c)
    t, rise = _sensor_step(lti)
    need = target_c - ambient_c
    if need <= 0 or rise[-1] <= need:
        raise ValueError(f"target {target_c:g} C is not reachable: full power holds {ambient_c + rise[-1]:.4g} C "
                         f"at ambient {ambient_c:g} C")
    return float(t[np.argmax(rise >= need)]) + spec.delay_s


def default_scenario(spec: Spec, target_c: float, ambient_c: float = AMBIENT_C, world_inputs: bool = True
                     ) -> TuneScenario:
    """Heat-up for 3x the full-power time, then one phase per disturbance (see the module docstring); a load
    step where the spec (or, ``world_inputs`` False, another plant of its ensemble) has no fan or flow."""
    heat_s = max(MIN_PHASE_S, HEATUP_FACTOR * full_power_time_s(spec, ambient_c, target_c))
    heat_s = math.ceil(heat_s / PHASE_ROUND_S) * PHASE_ROUND_S
    phase_s = math.ceil(max(MIN_PHASE_S, heat_s / 2) / PHASE_ROUND_S) * PHASE_ROUND_S
    events: tuple[Event, ...]
    if not (spec.world_inputs and world_inputs):
        events = (Event(heat_s, "load", None, -LOAD_FRACTION),)
    else:
        events = (Event(heat_s, "fan", None, FAN_KICK), Event(heat_s + phase_s, "flow", "hotend", FLOW_MM_S),
                  Event(heat_s + 2 * phase_s, "ambient", None, ambient_c + AMBIENT_STEP_C))
    return TuneScenario(float(target_c), events[-1].at_s + phase_s, ambient_c, events)


def preset_problem(preset: str, target_c: float, loop: str = "marlin", controller: ParamSpace | None = None) -> Problem:
    """A problem on a twin/plants.py preset with the default scenario (and by default Marlin's PID);
    ValueError names a bad preset."""
    if preset not in SPECS:
        raise ValueError(f"unknown plant preset {preset!r}; valid: {', '.join(SPECS)}")
    spec = SPECS[preset]
    return Problem(preset, spec, default_scenario(spec, target_c), loop, controller or param_space("pid", heater_of(preset)))


def heater_of(plant_name: str) -> str:
    """Which heater a plant preset is: "bed" for the bed presets, else "hotend"."""
    return "bed" if plant_name.startswith("bed") else "hotend"


def _value(event: Event) -> float:
    if not isinstance(event.value, (int, float)):
        raise ValueError(f"a {event.kind!r} event needs a number, not {event.value!r}")
    return float(event.value)


def _apply_to_plant(plant: Plant, event: Event) -> None:
    """A scenario event acting on a plant directly (batch lanes, Klipper's plants, the idealised loop)."""
    if event.kind == "load":
        if not isinstance(plant, LoadedPlant):
            raise ValueError("a load step needs a transfer-function plant")
        plant.set_load(_value(event))
        return
    inputs = {"fan": plant.fan, "flow": plant.flow_mm_s, "ambient": plant.ambient_c}
    if event.kind not in inputs:
        raise ValueError(f"a tuning scenario has no {event.kind!r} events")
    inputs[event.kind] = _value(event)
    plant.set_inputs(inputs["fan"], inputs["flow"], inputs["ambient"])


# -- the loops -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Traces:
    """Raw arrays of one chunk: (rows,), (rows, n), (rows, n), (n,); or, streamed, no rows and the totals."""

    t_s: np.ndarray
    temp_c: np.ndarray
    duty: np.ndarray
    tripped: np.ndarray
    streamed: ScoreTotals | None = None


def klipper_setup(problem: Problem, plant, params: Sequence[float] | np.ndarray | None = None) -> HeaterSetup:
    """The Klipper loop's heater on a plant: the log's own settings (sensor, max_power, smooth_time, pwm
    cycle, the resend rule of its version) where the problem has them, else Klipper's example extruder;
    max_temp raised to KLIPPER_MAX_TEMP_C so that only a real runaway trips; the gains given (a PID's
    ``params``), else the settings' own. On the kalico loop the same section on Kalico's heater (its own PWM
    rules), running the PID or, for Kalico's MPC, ``kalico_mpc_config`` of the params."""
    info = problem.klipper
    if info is None:
        setup = extruder_setup(plant, max_temp_c=KLIPPER_MAX_TEMP_C)
    else:
        setup = make_setup(replace(info, max_temp_c=max(info.max_temp_c, KLIPPER_MAX_TEMP_C)), "extruder", plant)
    config: HeaterConfig = setup.config
    if params is not None and problem.controller.pid:
        kp, ki, kd = (float(g) for g in params)
        config = replace(config, pid_kp=kp, pid_ki=ki, pid_kd=kd)
    if problem.loop == "kalico":
        carried = {name: getattr(config, name) for name in KALICO_CARRIED}
        config = KalicoHeaterConfig(**carried) if problem.controller.pid else \
            KalicoHeaterConfig(**carried, control=CONTROL_MPC, mpc=kalico_mpc_config(problem, params))
    return replace(setup, config=config, noise_lsb=problem.noise_lsb)


def kalico_mpc_config(problem: Problem, params: Sequence[float] | np.ndarray | None) -> MpcConfig:
    """Kalico's ``control: mpc`` options for the MPC family's parameters (firmware_port/firmwares.py
    ``kalico_mpc_space``; None: uncalibrated, what MPC_CALIBRATE starts from): the problem's heater_power (the
    nominal plant's input at full duty, on every member: a transfer function's unit is not a watt), and on a
    plant with a part fan ``cooling_fan`` and the table ``ambient_transfer, fan``."""
    fan_aware = problem.spec.world_inputs
    power_w = problem.heater_power_w
    if params is None:
        return MpcConfig(power_w, cooling_fan=fan_aware)
    capacity, responsiveness, ambient, fan = (float(v) for v in params)
    return MpcConfig(power_w, capacity, responsiveness, ambient, (ambient, fan) if fan_aware else (), fan_aware)


def _batch(problem: Problem, plants: Sequence[Plant], params: np.ndarray, seeds: Sequence[int],
           noise_lsb: Sequence[float], record: bool) -> BatchTwin | KlipperBatch:
    """A batch of the problem's loop, lane k running params[k] on plants[k] (lanes given one plant object
    share it) with seeds[k] and noise_lsb[k]; streaming the heater objective's inputs unless ``record``
    (Marlin's first reading, 15 samples, left out of them as run_chunk leaves it out of the trace)."""
    scenario = problem.scenario
    marlin = problem.loop == "marlin"
    heatup_end_s = scenario.disturbances_s[0] if scenario.disturbances_s else scenario.duration_s + 1.0
    score = None if record else score_spec(scenario.target_c, scenario.ambient_c, heatup_end_s, int(marlin))
    if marlin:
        return BatchTwin(list(plants), [problem.controller.make(row) for row in params], noise_lsb=list(noise_lsb),
                         seed=list(seeds), record=record, score=score)
    setups = [replace(klipper_setup(problem, plant, row), noise_lsb=noise) for plant, row, noise in
              zip(plants, params, noise_lsb)]
    return KlipperBatch(setups, seed=list(seeds), record=record, score=score)


def _stack(problem: Problem, params: np.ndarray, seeds: Sequence[int]) -> Stack:
    """One scalar twin per candidate, side by side as the lanes of one engine."""
    if problem.loop == "marlin":
        return Stack([_marlin_twin(replace(problem, seed=int(seed)), row) for row, seed in zip(params, seeds)])
    return Stack([KlipperTwin([klipper_setup(problem, make_problem_plant(problem), row)], seed=int(seed))
                  for row, seed in zip(params, seeds)])


def _drive(engine: BatchTwin | KlipperBatch | Stack, problem: Problem, events_of: Callable[[Plant], tuple[Event, ...]],
           record: bool) -> Traces:
    """Run an engine through the problem's scenario: the target, each event on each plant (``events_of``
    gives a plant its own events: its member's room), the run to the end; its raw traces (Marlin's first
    reading included), or a batch's streamed totals unless ``record``."""
    scenario = problem.scenario
    engine.hotend.target_c = round(scenario.target_c) if problem.loop == "marlin" else scenario.target_c
    for k, event in enumerate(scenario.events):
        engine.schedule_plants(event.at_s, functools.partial(_apply_kth, events_of=events_of, k=k))
    engine.run_until(scenario.duration_s)
    halted = np.atleast_1d(np.array(engine.halted, bool))
    if not record and not isinstance(engine, Stack):
        empty = np.zeros((0, engine.n_lanes))
        return Traces(np.zeros(0), empty, empty, halted, engine.score_totals())
    hotend = engine.result().hotend
    rows = len(hotend.t_s)
    return Traces(hotend.t_s, hotend.measured_c.reshape(rows, -1), hotend.duty.reshape(rows, -1), halted)


def _apply_kth(plant: Plant, events_of: Callable[[Plant], tuple[Event, ...]], k: int) -> None:
    _apply_to_plant(plant, events_of(plant)[k])


def run_lanes(problem: Problem, params: np.ndarray, record: bool = True, seeds: Sequence[int] | None = None,
              batched: bool | None = None) -> Traces:
    """The one runner: the candidates (N, d) as the lanes of one engine (a batch where the loop's lanes run
    them, ``Problem.batched``, else one scalar twin each), each on its seed of ``seeds`` (else the
    problem's), through the scenario (``_drive``)."""
    seeds = [problem.seed] * len(params) if seeds is None else seeds
    if problem.batched if batched is None else batched:
        plant = make_problem_plant(problem)
        engine: BatchTwin | KlipperBatch | Stack = _batch(problem, [plant] * len(params), params, seeds,
                                                          [problem.noise_lsb] * len(params), record)
    else:
        engine = _stack(problem, params, seeds)
    return _drive(engine, problem, lambda plant: problem.scenario.events, record)


def run_together(runs: Sequence[Problem], params: np.ndarray, record: bool = True) -> list[Traces]:
    """Every run's candidates (an ensemble's members on their seeds), the runs side by side as the lanes of
    one batch (each run its own plant, seed and noise, and its own room's events), one Traces per run, in
    order: one kernel run, not one per member. The runs must be batched and share the loop, the scenario's
    timing and the plants' dead time (``simulate`` groups them so)."""
    first, n = runs[0], len(params)
    plants = [make_problem_plant(r) for r in runs]
    events = {id(plant): r.scenario.events for plant, r in zip(plants, runs)}
    lanes = [(plant, r) for plant, r in zip(plants, runs) for _ in range(n)]
    engine = _batch(first, [p for p, _ in lanes], np.tile(params, (len(runs), 1)), [r.seed for _, r in lanes],
                    [r.noise_lsb for _, r in lanes], record)
    traces = _drive(engine, first, lambda plant: events[id(plant)], record)
    if first.loop == "marlin" and record:
        traces = Traces(traces.t_s[1:], traces.temp_c[1:], traces.duty[1:], traces.tripped)
    return [_lanes_of(traces, slice(k * n, (k + 1) * n)) for k in range(len(runs))]


def _lanes_of(traces: Traces, lanes: slice) -> Traces:
    streamed = None if traces.streamed is None else traces.streamed.lanes(lanes)
    return Traces(traces.t_s, traces.temp_c[:, lanes], traces.duty[:, lanes], traces.tripped[lanes], streamed)


def _marlin_twin(problem: Problem, row: np.ndarray | None) -> Twin:
    """A scalar firmware twin on the problem's plant running the candidate ``row`` (the firmware's own PID
    when None), at the scenario's ambient; its target and events are the caller's."""
    twin = Twin([make_problem_plant(problem)], "pid", controllers=[None if row is None else problem.controller.make(row)],
                seed=problem.seed, noise_lsb=problem.noise_lsb, engine=problem.engine)
    twin.set_ambient(problem.scenario.ambient_c)
    return twin


def run_scalars(problem: Problem, params: np.ndarray, seeds: Sequence[int] | None = None) -> Traces:
    """One scalar twin per candidate, whatever the lanes could run (``run_lanes``): what the batch is checked
    against."""
    return run_lanes(problem, params, True, seeds, batched=False)


def first_run_trips(problem: Problem, params: np.ndarray) -> list[tuple[float, str] | None]:
    """Where and why each candidate tripped on the problem's first run (the nominal plant on its first seed: lane
    0 of a ``Candidate.run``): (time in s, the firmware's words), None where it did not. A batch keeps only
    whether a lane tripped, so the candidates run again on scalar twins, which give the batch's readings."""
    first = problem.runs()[0]
    params = np.atleast_2d(np.asarray(params, float))
    if first.loop == "ideal":  # no protection in the papers' loop
        return [None] * len(params)
    engine = _stack(first, params, [first.seed] * len(params))
    _drive(engine, first, lambda plant: first.scenario.events, True)
    return [_trip_of(twin) for twin in engine.engines]


def _trip_of(twin) -> tuple[float, str] | None:
    """A scalar twin's first protection trip: (time in s, the firmware's words), or None."""
    if isinstance(twin, KlipperTwin):
        trips = twin.trips()
        return None if not trips or twin.shutdown_time_s is None else (twin.shutdown_time_s, trips[0].reason)
    trips = twin.result().protection_trips()
    return None if not trips else (trips[0][0], trips[0][1])


def _ideal_maps(lti: Lti, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-order hold of x' = A x + b u + E d on dt_s: (Phi, g, H)."""
    n, m = lti.a.shape[0], lti.e.shape[1]
    aug = np.zeros((n + 1 + m, n + 1 + m))
    aug[:n, :n], aug[:n, n], aug[:n, n + 1:] = lti.a, lti.b, lti.e
    import scipy.linalg
    disc = scipy.linalg.expm(aug * dt_s)
    return disc[:n, :n], disc[:n, n], disc[:n, n + 1:]


def _run_ideal(problem: Problem, gains: np.ndarray) -> Traces:
    """The papers' loop (module docstring); duty = controller output / full scale, unbounded."""
    scenario, dt = problem.scenario, IDEAL_DT_S
    plant = make_problem_plant(problem)
    kp, ki, kd = (np.asarray(gains, float) / COUNTS_PER_DUTY).T  # duty per degC
    n_steps = int(round(scenario.duration_s / dt))
    delay = int(round(problem.spec.delay_s / dt))
    pending = np.zeros((delay, len(gains)))
    x = np.repeat(plant.x[:, None], len(gains), axis=1)
    integral = np.zeros(len(gains))
    deriv = np.zeros(len(gains))
    prev_e = np.zeros(len(gains))  # the reference steps at t = 0: the derivative sees the kick
    tf_s = 1.0 / IDEAL_FILTER_PER_S
    events = list(scenario.events)
    maps = {}
    t_rows, temps, duties = [], [], []
    for k in range(n_steps + 1):
        t_s = k * dt
        while events and events[0].at_s <= t_s + 1e-9:
            _apply_to_plant(plant, events.pop(0))
        key = plant.conditions
        if key not in maps:
            maps[key] = _ideal_maps(plant.model.lti, dt)
        phi, g, h = maps[key]
        lti = plant.model.lti
        y = lti.c[SENSOR] @ x + lti.f[SENSOR] @ plant.d
        e = scenario.target_c - y
        integral += e * dt
        deriv = (tf_s * deriv + kd * (e - prev_e)) / (tf_s + dt)
        prev_e = e
        u = kp * e + ki * integral + deriv
        t_rows.append(t_s)
        temps.append(y)
        duties.append(u)
        if delay:
            pending = np.vstack((pending, u[None, :]))
            u, pending = pending[0], pending[1:]
        x = phi @ x + np.outer(g, u) + (h @ plant.d)[:, None]
    return Traces(np.array(t_rows), np.array(temps), np.array(duties), np.zeros(len(gains), bool))


def run_chunk(problem: Problem, params: np.ndarray, record: bool = True, seeds: Sequence[int] | None = None
              ) -> Traces:
    """One chunk of candidates on the problem's loop (a picklable task for dask), each on its seed of
    ``seeds`` (else all on the problem's); a batch streams the heater objective's inputs instead of
    keeping a trace unless ``record``."""
    if problem.loop == "ideal":
        return _run_ideal(problem, params)
    traces = run_lanes(problem, params, record, seeds)
    if traces.streamed is not None:
        return traces
    if problem.loop == "marlin":  # Marlin's first reading after reset sums 15 oversamples, not 16: it reads high
        traces = Traces(traces.t_s[1:], traces.temp_c[1:], traces.duty[1:], traces.tripped)
    return traces


def _chunks(params: np.ndarray) -> Iterator[np.ndarray]:
    for start in range(0, len(params), CHUNK_LANES):
        yield params[start:start + CHUNK_LANES]


def _join(parts: list[Traces]) -> Traces:
    rows = min(p.t_s.size for p in parts)  # every chunk runs on the same clock; guard a ragged end
    totals = [p.streamed for p in parts if p.streamed is not None]
    streamed = ScoreTotals.join(totals) if len(totals) == len(parts) else None
    return Traces(parts[0].t_s[:rows], np.hstack([p.temp_c[:rows] for p in parts]),
                  np.hstack([p.duty[:rows] for p in parts]), np.concatenate([p.tripped for p in parts]), streamed)


def simulate(problem: Problem, params, client=None, record: bool = True) -> Run:
    """Run candidates (N, d): rows of the problem's controller parameters (a PID's Kp, Ki, Kd on the
    0..255 scale) on every member of its ensemble; the run's lanes are member-major (members x N).
    A dask.distributed client runs the chunks. ``record=False``: batches stream the heater objective's
    inputs (``Run.streamed``) instead of keeping traces."""
    params = np.atleast_2d(np.asarray(params, float))
    space = problem.controller
    if params.ndim != 2 or params.shape[1] != space.dims:
        raise ValueError(f"parameters must be an (N, {space.dims}) array of {', '.join(space.names)}, "
                         f"got shape {params.shape}")
    if client is None:
        parts = _in_process(problem.runs(), params, record)
    else:
        members, chunks = zip(*[(member, chunk) for member in problem.runs() for chunk in _chunks(params)])
        parts = client.gather(client.map(run_chunk, members, chunks, [record] * len(members), pure=False))
    traces = _join(parts)
    gains = problem.plant_gains(params)
    return Run(traces.t_s, traces.temp_c, traces.duty, problem.scenario.target_c,
               problem.scenario.ambient_c, problem.scenario.disturbances_s, traces.tripped,
               None if gains is None else np.tile(gains, (len(problem.runs()), 1)), problem.input_full_scale,
               traces.streamed)


def _in_process(runs: list[Problem], params: np.ndarray, record: bool) -> list[Traces]:
    """Every run's traces, in order: the batched runs that can share a kernel run (the same dead time) as
    one batch (``run_together``), the others one run_chunk each."""
    parts: dict[int, Traces] = {}
    groups: dict[int, list[int]] = {}
    for k, r in enumerate(runs):
        if r.batched and r.loop != "ideal":
            groups.setdefault(r.spec.delay_ticks, []).append(k)
        else:
            parts[k] = run_chunk(r, params, record)
    for members in groups.values():
        for k, traces in zip(members, run_together([runs[k] for k in members], params, record)):
            parts[k] = traces
    return [parts[k] for k in range(len(runs))]


class Evaluator:
    """objective(population) for the optimisers: parameters (N, d) of the problem's controller -> costs (N,).

    Candidates outside the controller's declared bounds (or not finite) cost ``OUT_OF_RANGE_COST``.
    Counts evaluations; ``on_batch`` (if given) is called with each batch's costs (progress).
    """

    def __init__(self, problem: Problem, cost: Callable[[Run], np.ndarray], client=None,
                 on_batch: Callable[[np.ndarray], None] | None = None):
        self.problem, self.cost, self.client, self.on_batch = problem, cost, client, on_batch
        self.evaluations = 0
        self._seen: list[tuple[np.ndarray, np.ndarray]] = []  # (params, costs) of each batch

    def __repr__(self) -> str:
        return f"Evaluator({self.problem.name!r}, {self.problem.controller.name}, evaluations={self.evaluations})"

    def best(self, count: int, apart_rel: float) -> np.ndarray:
        """The ``count`` cheapest parameter rows evaluated, each apart from those before it by more than
        ``apart_rel`` (relative) in some parameter: the runners-up a proof may fall back on."""
        if not self._seen:
            return np.zeros((0, self.problem.controller.dims))
        params = np.vstack([p for p, _ in self._seen])
        costs = np.concatenate([c for _, c in self._seen])
        chosen: list[np.ndarray] = []
        for i in np.argsort(costs, kind="stable"):
            row = params[i]
            if costs[i] >= OUT_OF_RANGE_COST:
                break
            if all(np.any(np.abs(row - other) > apart_rel * np.maximum(np.abs(other), 1e-12)) for other in chosen):
                chosen.append(row)
                if len(chosen) == count:
                    break
        return np.array(chosen).reshape(-1, self.problem.controller.dims)

    def __call__(self, params) -> np.ndarray:
        params = np.atleast_2d(np.asarray(params, float))
        valid = self.problem.controller.inside(params)
        costs = np.full(len(params), OUT_OF_RANGE_COST)
        if valid.any():
            costs[valid] = self.problem.reduce(self.cost(simulate(self.problem, params[valid], self.client,
                                                                  needs_trace(self.cost))))
        self.evaluations += len(params)
        self._seen.append((params, costs))
        if self.on_batch is not None:
            self.on_batch(costs)
        return costs


# -- the firmware's own autotune ---------------------------------------------------------------------
def marlin_autotune(problem: Problem, cycles: int = M303_CYCLES) -> Gains:
    """M303 E0 S<target> C<cycles> on a Marlin twin of the problem's plant (at ambient, no
    disturbances): the gains it prints. ValueError if the autotune fails."""
    quiet = replace(problem, scenario=replace(problem.scenario, events=()))
    twin = _marlin_twin(quiet, None)  # the firmware's own PID runs M303
    tune = twin.board.start_autotune(HOTEND_CHANNEL, int(round(problem.scenario.target_c)), cycles)
    limit_s = AUTOTUNE_TIMEOUT_S
    while not tune.done and twin.time_s < limit_s:
        twin.run_until(twin.time_s + AUTOTUNE_POLL_S)
    if not tune.succeeded or tune.gains is None:
        raise ValueError(f"M303 failed on {problem.name}: " + " | ".join(twin.console.lines()[-2:]))
    kp, ki, kd = tune.gains
    return Gains(kp, ki, kd)


def klipper_autotune(problem: Problem) -> Gains:
    """PID_CALIBRATE HEATER=extruder TARGET=<target> on a twin of the problem's plant: Klipper's, or on the
    kalico loop Kalico's (its default TOLERANCE). ValueError if it fails."""
    twin = KlipperTwin([klipper_setup(replace(problem, noise_lsb=0.0), make_problem_plant(problem))])
    calibrate = twin.kalico_pid_calibrate if problem.loop == "kalico" else twin.pid_calibrate
    with _calibrating(twin, problem, "PID_CALIBRATE"):
        result = calibrate("extruder", problem.scenario.target_c)
    return Gains(result.kp, result.ki, result.kd)


def kalico_mpc_autotune(problem: Problem) -> np.ndarray:
    """MPC_CALIBRATE HEATER=extruder TARGET=<target> on a Kalico twin of the problem's plant running an
    uncalibrated MPC (``kalico_mpc_config``): the constants it saves, as the family's parameters (block heat
    capacity, sensor responsiveness, ambient transfer, the fan table's last entry: the transfer at full fan,
    its middle breakpoints dropped). ValueError if it fails."""
    twin = KlipperTwin([klipper_setup(replace(problem, noise_lsb=0.0), make_problem_plant(problem))])
    with _calibrating(twin, problem, "MPC_CALIBRATE"):
        result = twin.mpc_calibrate("extruder", target_c=problem.scenario.target_c)
    saved = result.config(kalico_mpc_config(problem, None))
    ambient = saved.ambient_transfer_w_k
    fans = saved.fan_ambient_transfer_w_k
    return np.array([saved.block_heat_capacity_j_k, saved.sensor_responsiveness_per_s, ambient,
                     fans[-1] if fans else ambient], float)


@contextmanager
def _calibrating(twin: KlipperTwin, problem: Problem, command: str) -> Iterator[None]:
    """A calibration on a Klipper-family twin: its CommandError as a ValueError naming the command, the plant
    and why it failed (the shutdown's message where the printer shut down)."""
    try:
        yield
    except CommandError as exc:
        why = (twin.shutdown_message or str(exc)).splitlines()[0]
        raise ValueError(f"{command} failed on {problem.name}: {why}") from None


def mpc_autotune(problem: Problem) -> np.ndarray:
    """M306 T on a Marlin twin of the problem's plant running the problem's MPC (at ambient, no
    disturbances): the constants it finds, as the family's parameters (C, R, A, F). ValueError if it fails."""
    quiet = replace(problem, scenario=replace(problem.scenario, events=()))
    twin = _marlin_twin(quiet, problem.controller.defaults)
    tune = MpcAutotune(twin.board)
    tune.start(twin.board.now_ms)
    twin.board.begin_tune(tune, HOTEND_CHANNEL)
    while twin.board.autotune is not None and not twin.board.halted and twin.time_s < AUTOTUNE_TIMEOUT_S:
        twin.run_until(twin.time_s + AUTOTUNE_POLL_S)
    if not tune.succeeded:
        raise ValueError(f"M306 T failed on {problem.name}: " + " | ".join(twin.console.lines()[-2:]))
    constants = tune.mpc.constants
    return np.array([constants.block_heat_capacity_j_k, constants.sensor_responsiveness_per_s,
                     constants.ambient_xfer_w_k, constants.fan_ambient_xfer_w_k])


def firmware_autotune(problem: Problem) -> tuple[str, np.ndarray]:
    """The firmware's own autotune of the problem's controller family on its plant, in its loop's firmware
    (the idealised loop has none: Marlin's): (its name, the parameters it gives). ValueError when it fails
    or the family has none."""
    kind = problem.controller.autotune
    if kind == "M303":
        if klipper_family(problem.loop):
            gains = klipper_autotune(problem)
            return "PID_CALIBRATE", np.array([gains.kp, gains.ki, gains.kd])
        gains = marlin_autotune(problem)
        return f"M303 C{M303_CYCLES}", np.array([gains.kp, gains.ki, gains.kd])
    if kind == "M306 T":
        return kind, mpc_autotune(problem)
    if kind == "MPC_CALIBRATE":
        return kind, kalico_mpc_autotune(problem)
    raise ValueError(f"controller {problem.controller.name} has no firmware autotune")


# -- candidates: the rules' gains, scored together ---------------------------------------------------
@dataclass(frozen=True)
class Candidate:
    """One tuned result: where it came from, its parameters, its cost and its run on the twin."""

    method: str
    params: np.ndarray
    cost: float  # the ensemble's statistic (the cost itself without an ensemble)
    run: Run  # one lane per ensemble member, the nominal plant first
    history: np.ndarray | None = None  # an optimiser's best cost per iteration
    member_costs: np.ndarray | None = None  # (members,)

    @property
    def gains(self) -> Gains:
        """A PID family's parameters as gains (Kp, Ki, Kd on the 0..255 scale)."""
        return Gains(*(float(v) for v in self.params))


def rule_gains(problem: Problem, names: list[str]) -> tuple[dict[str, Gains], dict[str, str]]:
    """Each named rule's gains for the problem's plant (tools/tuning/rules) as its linear model, with
    the firmware loop's own delay added where a firmware is in the loop (tools/ident/fit.py
    CONTROL_DELAY_S, as twin-fit tunes; none on the papers' idealised loop); and, for the rules that
    give none on this model, why (a rule's ValueError). A radiating plant is linearised at the target
    (its loss the secant conductance there, part fan off)."""
    spec, scenario = problem.spec, problem.scenario
    at_target = spec.conditions(0.0, 0.0, scenario.ambient_c, scenario.target_c) \
        if isinstance(spec, Lumped) and not spec.linear else None
    model = model_of(spec, at_target)
    if problem.loop != "ideal":
        model = model.delayed(CONTROL_DELAY_S)
    gains, failures = {}, {}
    for name in names:
        try:
            gains[name] = tune(name, model)
        except ValueError as exc:
            failures[name] = str(exc)
    return gains, failures


def score(problem: Problem, cost: Callable[[Run], np.ndarray], candidates: Mapping[str, np.ndarray | Gains],
          client=None) -> list[Candidate]:
    """Every candidate (parameters, or gains of a PID family) in one batch, clipped into the controller's
    bounds, best first."""
    names = list(candidates)
    bounds = problem.controller.bounds
    table = np.array([[c.kp, c.ki, c.kd] if isinstance(c, Gains) else np.ravel(c) for c in candidates.values()],
                     float)
    table = np.array([problem.controller.hold(row) for row in np.clip(table, bounds[:, 0], bounds[:, 1])])
    return sorted(runs(problem, cost, table, names, client), key=lambda c: c.cost)


def runs(problem: Problem, cost: Callable[[Run], np.ndarray], table: np.ndarray, names: list[str],
         client=None, histories: list[np.ndarray | None] | None = None) -> list[Candidate]:
    """Candidates (rows of ``table``, named) run on every member and scored, in the given order."""
    run = simulate(problem, table, client)
    n = len(table)
    member_costs = cost(run).reshape(-1, n)
    reduced = problem.reduce(member_costs)
    histories = histories or [None] * n
    return [Candidate(name, table[i], float(reduced[i]), run.lanes(list(range(i, run.n, n))), histories[i],
                      member_costs[:, i]) for i, name in enumerate(names)]
