"""Batch twins: N hotend twins advanced together as lanes: candidate controllers, plants and noise.

Every lane is a Marlin board (firmware_port.marlin.lanes: ADC, soft PWM, thermal protection)
running its own controller on its own plant, with its own ADC noise; all lanes share the clock.
A tuner evaluates a whole population (times an ensemble of plants and noise seeds) in one run;
tests keep each lane equal to a scalar ``Twin`` (tests/twin/test_batch_paths.py, tests/firmware_port/marlin/test_lanes.py).

- Controllers: any family with a lane law (firmware_port/lane_law.py: ``PidFixed`` in either
  prev-temperature mode, or ``PidGains``; ``BangBangHotend``, ``FuzzyPi``, ``FuzzyPid``, a user's):
  one family per batch (``BatchTwin.accepts``).
- Plants: one for every lane, or one per lane; lanes given the same plant object share it (its
  model, and the scenario's events, which act on ``batch.plants``). Linear plants, dead time (exact
  on the tick grid) and the radiating loss (relinearised at the block's 0.5 C bin every period,
  as the scalar engine does).
- Noise: ``noise_lsb`` and ``seed`` for every lane or per lane. Common random numbers: lanes that
  name the same seed draw the same normal sequence (scaled by their own noise_lsb), and it is the
  one ``Twin(plants, seed=seed, noise_lsb=...)``'s hotend chain draws (one normal per ADC sample, in
  order; ``SeedSequence(seed).spawn``'s first stream, ``twin.sensor.seeded_chains``). So a lane with
  seed s and noise n reads what that scalar twin reads, and all candidates in a group see the same
  noise. Without a seed, a ``sensor`` chain with noise lends its own generator as the one stream.
- Shared prefix (the compiled loop): lanes in the same state, on the same noise and
  with the same parameters outside their controllers' tuning run the same periods until each
  controller first reads its own tuning (a PID's heat-up at full power, before its band): one lane
  runs them and the others take its state there (``_shared_prefix``; ``shared_lane_periods``
  counts them). Each lane still equals itself run alone, bit for bit (tests/twin/test_shared_prefix.py).
- Records (``record=True``): one row per reading, arrays (rows, N). With ``score=ScoreSpec(...)``
  the lanes also accumulate the heater objective's inputs (twin/streaming.py); ``record=False``
  then keeps no trace: memory per lane independent of the horizon.

Two implementations of the stretch between scenario events, equal bit for bit where both run:
period by period on numpy lanes, or ``twin.batch_kernel``'s compiled loop over lanes and periods
(``kernel="numba"``, the default when numba compiles), spread over threads (the loop releases
the GIL; ``threads``, default every CPU this process may use, or ``HEATER_TWIN_THREADS``). The
numpy lanes run linear plants (dead time too) and laws that do not read the board; with
``kernel="numpy"`` (the default without numba) the others run on the loop, as plain Python where
numba is missing: the same answers, slower (docs/performance.md). A faulted sensor chain, a
thermistor placed on a gradient or a Steinhart-Hart part (no table of switching temperatures)
always take the numpy lanes. The
shared clock (ADC phase, soft-PWM counter, millis) is planned once per stretch and cached, and the
plant's tables once per model, so a tuner that replays the same scenario pays only for the lanes.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from firmware_port.controller import Tunable
from firmware_port.fixed import wrap_s32
from firmware_port.lane_law import BOARD_INPUTS, LAWS, LaneLaw, field_names, law_for
from firmware_port.marlin.adc import AdcSequencer
from firmware_port.marlin.constants import E_STEPS_PER_MM, MIN_ADC_ISR_LOOPS, SOFT_PWM_MAX, SOFT_PWM_PERIOD_TICKS, \
    TICKS_PER_READING, ticks_to_ms
from firmware_port.marlin.lanes import HotendLanes, lookup_q5
from firmware_port.marlin.pid import PID_LAW, PREV_TEMP_EVERY_SAMPLE, PidFixed, PidGains
from firmware_port.thermistor import ADC_COUNTS, ADC_MAX, KELVIN_OFFSET, MAX_RAW_THERMISTOR_VALUE, \
    TEMP_FRAC_BITS, TEMP_ONE, TempTable
from twin import adc_table, batch_kernel as bk, lane_ring
from twin.clock import TICK_S, EventQueue, ticks_at
from twin.engine import FAN_SPEED_MAX, m104_target
from twin.engine_protocol import LaneHeater, Runs, Trip, each_plant
from twin.lane_noise import draw, noise_levels, seed_streams
from twin.lane_tables import MAX_SAMPLES, Tables, bin_tables, block_bin, linear_tables
from twin.limits import DURATION_MAX_S, TARGET_RANGE_C, THREADS_ENV, check_trace_bytes, checked
from twin.linear import BLOCK
from twin.result import RunResult
from twin.sensor import SensorChain
from twin.streaming import ScoreSpec, ScoreTotals

MIN_LANES_PER_THREAD = 4  # fewer lanes than this per thread run on the calling thread
BIN_MARGIN = 40  # radiating plants: bins (of 0.5 C) built beyond the ones the lanes need, each way
TARGET_HEADROOM_C = 20.0  # radiating plants: bins built up front to this far above the target (the block leads)
# A record row's memory: per lane temp_q5 and amount (int16), block and sensor (float64); per row its time and target.
RECORD_LANE_BYTES, RECORD_ROW_BYTES = 20, 16


@dataclass
class LaneState:
    """What the kernel advances per lane (besides the plant states): the board and the law's state
    (records), the dead-time ring, the objective."""

    board: np.recarray
    state: np.recarray
    ring: np.ndarray
    score_i: np.ndarray
    score_f: np.ndarray

    def copy(self) -> LaneState:
        return LaneState(*(getattr(self, f.name).copy() for f in dataclasses.fields(self)))


@dataclass
class LaneGroup:
    """Lanes that share a plant: their global lane numbers and their plant states (n_x, lanes)."""

    plant: Any  # the plant API of twin/linear.py (a Plant: model, d, x, delay_ticks, linear, spec)
    lanes: np.ndarray
    x: np.ndarray
    bins: tuple[int, int] | None = None  # radiating: the block bins the tables hold, first and last
    fed: tuple[float, int, float] = (0.0, 0, 0.0)  # filament fed (mm) at a tick, and the flow (mm/s) since


def lane_threads(threads: int | None) -> int:
    if threads is not None:
        return max(1, int(threads))
    if THREADS_ENV in os.environ:
        value = os.environ[THREADS_ENV]
        if not value.isdigit() or int(value) < 1:
            raise ValueError(f"{THREADS_ENV}={value!r}: must be a positive integer")
        return int(value)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@functools.lru_cache(maxsize=4)
def _pool(workers: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="batch-lanes")


def _control_lanes(controllers: Sequence[PidGains | object], prev_temp_mode: str) -> tuple[LaneLaw, Any]:
    """The lanes' lane law and what the numpy lanes run; TypeError names a lane it cannot run."""
    laws = [PID_LAW if isinstance(c, PidGains) else law_for(c) for c in controllers]  # PidGains: a PID lane
    law = cast(LaneLaw, laws[0])  # (lane 0's: None raises below first)
    for lane, (item, other) in enumerate(zip(controllers, laws)):
        if other is None:
            raise TypeError(f"lane {lane}: a batch runs controllers with a lane law (firmware_port/lane_law.py: "
                            f"{', '.join(sorted(c.__name__ for c in LAWS))}, or PidGains), not {item!r}")
        if other is not law:
            raise TypeError(f"lane {lane}: one controller family per batch, {law.controller.__name__} in lane 0, "
                            f"not {other.controller.__name__}")
    return law, law.lanes(list(controllers), prev_temp_mode)


class BatchTwin(Runs):
    """N hotends on one clock; ``run_until`` then read ``t_s``, ``measured_c``, ``duty`` ... or ``score_totals()``.

    Records one row per firmware reading: arrays of shape (rows, N) for the firmware's measured
    temperature, the true block and sensor temperatures and the duty (amount / 127). Follows the
    engine protocol (twin/engine_protocol.py) with a lane per controller.
    """

    @staticmethod
    def accepts(controller: object, prev_temp_mode: str | None = None) -> bool:
        """Whether a lane can run this controller: one whose family declares a lane law (a PID in
        ``prev_temp_mode``, when given), on either kernel."""
        law = law_for(controller)
        if law is None:
            return False
        return prev_temp_mode is None or not isinstance(controller, PidFixed) or \
            controller.prev_temp_mode == prev_temp_mode

    @staticmethod
    def needs_kernel(plant) -> bool:
        """Whether a plant needs the loop of ``batch_kernel``: a radiating loss (the numpy lanes run linear
        plants, with or without dead time)."""
        return not getattr(plant, "linear", True)

    def numpy_lanes_run(self) -> bool:
        """Whether the numpy lanes run this batch: linear plants (``needs_kernel``) and a law that does not read
        the board (kernel='numpy' runs the others on ``batch_kernel``'s loop, plain Python without numba)."""
        return not self.law.reads_board and not any(self.needs_kernel(g.plant) for g in self.groups)

    def __init__(self, plant, controllers: Sequence[PidGains | Tunable | object], *,
                 prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE, sensor: SensorChain | None = None,
                 noise_lsb: float | Sequence[float] | None = None, seed: int | Sequence[int] | None = None,
                 kernel: str | None = None, record: bool = True, score: ScoreSpec | None = None,
                 threads: int | None = None):
        self.kernel = bk.default_kernel() if kernel is None else kernel
        if self.kernel not in bk.KERNELS:
            raise ValueError(f"kernel={self.kernel!r}: must be one of {', '.join(bk.KERNELS)}")
        self.n_lanes = len(controllers)
        if not self.n_lanes:
            raise ValueError("a batch needs at least one lane")
        self.controllers = tuple(controllers)  # what each lane was built from
        self.law, control = _control_lanes(controllers, prev_temp_mode)
        self.lanes = HotendLanes(control)
        self.groups = self._group(plant)
        self.sensor = sensor if sensor is not None else SensorChain()
        self._noise_setup(noise_lsb, seed)
        self.record, self.score = record, score
        self.threads = lane_threads(threads)
        self.tick = 0
        self._events = EventQueue()
        self._chunks: list[tuple] = []  # records: (t_s (R,), temp_q5, amount, block_c, sensor_c (N, R))
        self._targets: list[int] = []  # the target in force at each row
        self._rows = 0  # readings so far
        self._first_s: float | None = None  # the first scored reading's time
        n = self.n_lanes
        self._adc_hint = np.zeros(n, np.int64)  # the kernel's last ADC count: a search start
        self._params = self.law.pack_params(control).view(np.recarray)
        delay = max(g.plant.delay_ticks for g in self.groups)
        self._delay = delay
        self._ring = np.zeros((n, delay // SOFT_PWM_PERIOD_TICKS + 6 if delay else 1, 2), np.int64)
        self._ring_state = np.zeros((n, 2), np.int64)  # head, length
        self.score_i = np.zeros((n, bk.N_SCORE), np.int64)
        self.score_f = np.zeros((n, bk.N_SCORE))
        self.score_f[:, bk.MAX_BEYOND] = -np.inf
        self.shared_lane_periods = 0  # periods lanes took from another lane's run (``_shared_prefix``)

    # -- construction --------------------------------------------------------------------------------
    def _group(self, plant) -> list[LaneGroup]:
        plants = list(plant) if isinstance(plant, (list, tuple)) else [plant] * self.n_lanes
        if len(plants) != self.n_lanes:
            raise ValueError(f"plants: one, or one per lane ({self.n_lanes}), not {len(plants)}")
        if len({p.delay_ticks for p in plants}) > 1:
            raise ValueError("plants: every lane's plant needs the same dead time")
        groups: dict[int, list[int]] = {}
        for lane, p in enumerate(plants):
            groups.setdefault(id(p), []).append(lane)
        out = []
        for lanes in groups.values():
            p = plants[lanes[0]]
            out.append(LaneGroup(p, np.array(lanes, np.int64), np.repeat(p.x[:, None], len(lanes), axis=1)))
        return out

    def _noise_setup(self, noise_lsb, seed) -> None:
        """Per lane: the noise (LSB) and the stream it scales; the streams' generators."""
        n = self.n_lanes
        self.noise_lsb = noise_levels(self.sensor.noise_lsb if noise_lsb is None else noise_lsb, n)
        if seed is None:
            self.streams = np.zeros(n, np.int64)
            self._generators = [self.sensor.rng]
            return
        self.streams, self._generators = seed_streams(seed, n)

    # -- the outside world ---------------------------------------------------------------------------
    @property
    def plants(self) -> list:
        """The distinct plants (one per group of lanes): a scenario's events act on each."""
        return [g.plant for g in self.groups]

    @property
    def plant(self):
        """The plant every lane runs (AttributeError when lanes run several)."""
        if len(self.groups) > 1:
            raise AttributeError("the lanes run several plants: see BatchTwin.plants")
        return self.groups[0].plant

    @property
    def x(self) -> np.ndarray:
        """The plant states (n_x, N) when every lane runs one plant."""
        return self.groups[0].x if len(self.groups) == 1 else np.hstack([g.x for g in self.groups])

    def schedule(self, at_s: float, action: Callable[[BatchTwin], None]) -> None:
        """Run ``action(batch)`` at the first tick at or after ``at_s``."""
        self._events.push(ticks_at(checked("at_s", at_s, 0.0, DURATION_MAX_S, "s")), action, self)

    def schedule_plants(self, at_s: float, action: Callable[[Any], None]) -> None:
        """Run ``action(plant)`` on every distinct plant at ``at_s`` (the lanes' states are the batch's own:
        the action changes the plant's inputs, never its state)."""
        self.schedule(at_s, each_plant(action))

    def set_target(self, target_c: int) -> None:
        checked("target_c", target_c, *TARGET_RANGE_C, "C")
        self.lanes.set_target(target_c)

    @property
    def time_s(self) -> float:
        return self.tick * TICK_S

    @property
    def handles(self) -> dict[str, LaneHeater]:
        """The hotend's handle: every lane's target (whole degrees, as M104), the lanes' controllers."""
        return {"hotend": LaneHeater("hotend", lambda: self.lanes.target_c,
                                     lambda value: self.set_target(m104_target(value)), lambda: self.controllers)}

    @property
    def halted(self) -> np.ndarray:
        """Per lane: its board halted (a protection trip)."""
        return self.lanes.halted.copy()

    def trips(self) -> list[Trip]:
        """Each halted lane's trip, in Marlin's words (``lanes.trip``)."""
        return [Trip(int(lane), "hotend", str(self.lanes.trip[lane])) for lane in np.flatnonzero(self.lanes.halted)]

    def __repr__(self) -> str:
        plants = ", ".join(sorted({getattr(p, "preset", type(p).__name__) for p in self.plants}))
        return f"BatchTwin({self.n_lanes} lanes of {self.law.controller.__name__} on {plants}, " \
               f"kernel={self.kernel!r}, t={self.time_s:g} s, {int(self.lanes.halted.sum())} halted)"

    def result(self, label: str = "batch") -> RunResult:
        if not self.record:
            raise ValueError("this batch keeps no trace (record=False): read score_totals()")
        n = len(self._targets)
        target = np.repeat(np.array(self._targets, dtype=float).reshape(n, 1), self.n_lanes, axis=1)
        hotend = {"target_c": target, "measured_c": self._measured_c, "block_c": self._block_c,
                  "sensor_c": self._sensor_c, "duty": self._duty}
        return RunResult.from_columns(self._t_s, {"hotend": hotend}, label=f"{label}, {self.n_lanes} lanes")

    def score_totals(self) -> ScoreTotals:
        """The heater objective's inputs accumulated so far (ValueError without a ``score``, or before
        the heat-up's end: the totals of a run cut short would not be the trace's)."""
        if self.score is None:
            raise ValueError("this batch scores nothing: give it score=ScoreSpec(...)")
        if self._first_s is None or self.tick * TICK_S < self.score.heatup_end_s:
            raise ValueError(f"the run has not reached the end of the heat-up ({self.score.heatup_end_s:g} s)")
        si, sf = self.score_i, self.score_f
        holding_s = (self._reading_tick(si[:, bk.FIRST_ROW])) * TICK_S
        return ScoreTotals(self._first_s, holding_s, si[:, bk.REACHED].astype(bool), sf[:, bk.MAX_BEYOND].copy(),
                           sf[:, bk.ABS_ERROR_SUM].copy(), si[:, bk.HOLD_ROWS].copy(),
                           sf[:, bk.DUTY_STEP_SUM] / SOFT_PWM_MAX)

    def run_until(self, t_s: float) -> None:
        """Advance every lane to ``t_s`` seconds (at most DURATION_MAX_S; ValueError if the records would
        outgrow memory)."""
        checked("t_s", t_s, 0.0, DURATION_MAX_S, "s")
        if self.record:
            rows = self._rows + max(0.0, t_s - self.tick * TICK_S) / (TICKS_PER_READING * TICK_S)
            check_trace_bytes(t_s, rows * (RECORD_LANE_BYTES * self.n_lanes + RECORD_ROW_BYTES),
                              "keep no trace (record=False, score=ScoreSpec(...)), run fewer lanes or run shorter")
        end = ticks_at(t_s)
        while self.tick < end:
            for _, action, args in self._events.pop_due(self.tick):
                action(*args)
            due = self._events.next_at()
            stop = end if due is None else min(end, due)
            if stop > self.tick:
                self._run_to(stop)

    def _run_to(self, stop: int) -> None:
        if self._kernel_sensor() and (self.kernel == "numba" or not self.numpy_lanes_run()):
            self._run_kernel(stop)
            return
        if not self.numpy_lanes_run():
            raise ValueError("this sensor chain (faulted, on a gradient, or a Steinhart-Hart part) runs on the "
                             "numpy lanes, which need a linear plant and a law that does not read the board")
        while self.tick < stop:
            self._period(min(stop - self.tick, self.lanes.adc.ticks_to_reading()))

    def _kernel_sensor(self) -> bool:
        """Whether the compiled loop can convert this chain's samples: a healthy beta part at the node."""
        chain = self.sensor
        return chain.fault is None and not chain.gradient_fraction and adc_table.adc_edges_c(chain.divider) is not None

    # -- readings and their times ---------------------------------------------------------------------
    def _reading_tick(self, rows: np.ndarray) -> np.ndarray:
        """The tick of global reading rows (readings come every TICKS_PER_READING after the first)."""
        return self._first_reading_tick + TICKS_PER_READING * np.asarray(rows, np.int64)

    def _note_readings(self, reading_ticks: np.ndarray) -> np.ndarray:
        """Global row numbers of this stretch's readings; remembers the first reading's tick."""
        if self._rows == 0 and len(reading_ticks):
            self._first_reading_tick = int(reading_ticks[0])
        rows = self._rows + np.arange(len(reading_ticks))
        if self.score is not None and self._first_s is None and len(reading_ticks):
            skip = self.score.skip_rows
            self._first_s = float(self._reading_tick(np.array([skip]))[0] * TICK_S)
        return rows

    def _flags(self, reading_ticks: np.ndarray, rows: np.ndarray) -> np.ndarray:
        if self.score is None:
            return np.zeros(len(rows), np.int64)
        return self.score.flags(reading_ticks * TICK_S, (reading_ticks + TICKS_PER_READING) * TICK_S, rows)

    # -- numpy lanes, one control period at a time ------------------------------------------
    def _period(self, n: int) -> None:
        """As ``Twin._fast_period``, on all lanes: PWM pulses summed through the step table.

        The float arithmetic is ``batch_kernel``'s, in the same order, so both give the same bits.
        """
        lanes = self.lanes
        offsets = tuple(lanes.adc.sample_offsets(n)[0])
        kinds = ((n, offsets),)
        pulses = self._plant_pulses(lanes.pulses(n), n)
        s = np.array(offsets, dtype=np.int64)[:, None]
        noise = self._lane_noise(draw(self._generators, len(offsets))) if self.noise_lsb.any() else None
        samples = np.zeros((len(offsets), self.n_lanes), np.int64)
        sensor_cs = []
        for group in self.groups:
            t = linear_tables(group.plant.model, group.plant.d, kinds, TICKS_PER_READING)
            sensor_c = _dot(t.px[0, 0].T, group.x) + t.pdd[0, 0][:, None]
            sstep = t.sensor_steps[0]
            for alpha, beta in pulses:
                alpha, beta = (np.broadcast_to(e, self.n_lanes)[group.lanes] for e in (alpha, beta))
                sensor_c = sensor_c + (sstep[np.maximum(s - alpha, 0)] - sstep[np.maximum(s - beta, 0)])
            samples[:, group.lanes] = self._convert(sensor_c, s, None if noise is None else noise[:, group.lanes])
            sensor_cs.append(t)
        lanes.skip(n, samples)
        pins_before = lanes.pins.copy()
        reading = lanes.adc.raw_ready
        lanes.task()
        for group, t in zip(self.groups, sensor_cs):
            x = _dot(t.fx[0, 0], group.x) + t.fdd[0, 0][:, None]
            for alpha, beta in pulses:
                alpha, beta = (np.broadcast_to(e, self.n_lanes)[group.lanes] for e in (alpha, beta))
                x = x + (t.steps[0][n - alpha] - t.steps[0][n - beta]).T
            # the main loop may have written the pin for the last tick (a dead time's ring takes that in below)
            diff = (lanes.pins.astype(float) - pins_before)[group.lanes] if not self._delay else 0.0
            group.x = x + t.io[0, 0, :-1][:, None] * diff
        if self._delay:
            lane_ring.cut_last(self._ring, self._ring_state, pins_before & ~lanes.pins)
        self.tick += n
        if reading:
            self._numpy_reading(sensor_cs)

    def _plant_pulses(self, pulses: list[tuple], n: int) -> list[tuple]:
        """The soft PWM's pulses this period, or with a dead time the ones the plant sees: the ring's,
        ``delay`` ticks late (``lane_ring``, as ``batch_kernel._plant_pulses``)."""
        if not self._delay:
            return pulses
        for alpha, beta in pulses:
            lane_ring.push(self._ring, self._ring_state, self.tick + alpha, self.tick + np.asarray(beta))
        return lane_ring.delayed(self._ring, self._ring_state, self.tick, n, self._delay)

    def _numpy_reading(self, tables: list[Tables]) -> None:
        lanes = self.lanes
        rows = self._note_readings(np.array([self.tick]))
        if self.record:
            block, sensor = np.zeros((self.n_lanes, 1)), np.zeros((self.n_lanes, 1))
            for group, t in zip(self.groups, tables):
                block[group.lanes, 0] = _output(t.io[0, 1], group.x)
                sensor[group.lanes, 0] = _output(t.io[0, 2], group.x)
            self._targets.append(lanes.target_c)
            self._chunks.append((np.array([self.tick * TICK_S]), lanes.temp_q5[:, None].astype(np.int16),
                                 lanes.amount[:, None].astype(np.int16), block, sensor))
        flags = int(self._flags(np.array([self.tick]), rows)[0])
        if flags & bk.SCORED:
            _score_lanes(self.score_i, self.score_f, self._score_params(), int(rows[0]), flags,
                         lanes.temp_q5 / TEMP_ONE, lanes.amount.astype(float))
        self._rows += 1

    def _convert(self, sensor_c: np.ndarray, s: np.ndarray, noise: np.ndarray | None) -> np.ndarray:
        """The lanes' ADC counts (J, lanes) of sensor temperatures at sample offsets s."""
        edges = adc_table.adc_edges_c(self.sensor.divider) if self._kernel_sensor() else None
        if noise is None and edges is not None:
            return adc_table.convert(edges, sensor_c)
        return self.sensor.convert_with(sensor_c, self.tick + s, noise)

    def _lane_noise(self, z: np.ndarray) -> np.ndarray:
        """Each lane's noise in LSB at each sample, (J, N): its level times its stream."""
        return (self.noise_lsb[:, None] * z[self.streams]).T

    def _score_params(self) -> np.ndarray:
        spec = self.score
        assert spec is not None
        return np.array([spec.target_c, spec.sign, spec.band_c])

    # -- the compiled kernel, a whole stretch at once ---------------------------------------
    def _run_kernel(self, stop: int) -> None:
        lanes = self.lanes
        adc = lanes.adc
        plan, kinds, end = _clock_plan(adc.phase, adc.temp_count, lanes.pwm_count, self.tick, stop)
        reading = plan.reading == 1
        reading_ticks = (plan.tick + plan.n_ticks)[reading]
        rows = self._note_readings(reading_ticks)
        n_rows = len(rows)
        if self.score is not None:
            plan = plan.copy()
            plan.score_flags[reading] = self._flags(reading_ticks, rows)
            plan.flags.writeable = False  # as the cached plans: one compiled signature
        z = draw(self._generators, int(plan.z_first[-1] + _n_samples(plan[-1]))) if self.noise_lsb.any() else \
            np.zeros((1, 1))
        records = bk.Records(*(np.zeros((self.n_lanes, n_rows if self.record else 0), dtype)
                               for dtype in (np.int16, np.int16, float, float)))
        state = LaneState(self._pack(), self.law.read_state(self.lanes.control).view(np.recarray), self._ring,
                          self.score_i, self.score_f)
        for group in self.groups:
            self._run_group(group, self._board_plan(group, plan), kinds, state, z, records)
        self._unpack(state.board)
        self.law.write_state(self.lanes.control, state.state)
        adc.phase, adc.temp_count, lanes.pwm_count = end
        adc.raw_ready = False
        if n_rows:
            lanes.runaway_c = lanes.target_c
            if self.record:
                self._chunks.append((reading_ticks * TICK_S, *records))
                self._targets.extend([lanes.target_c] * n_rows)
        self._rows += n_rows
        lanes.ticks += stop - self.tick
        self.tick = stop

    def _board_plan(self, group: LaneGroup, plan: np.recarray) -> np.recarray:
        """The plan with the E stepper's position at each reading, for a law that reads the board: the
        filament the group's plant has been fed (its flow since it last changed), as ``Twin`` moves it."""
        if not self.law.reads_board:
            return plan
        fed_mm, fed_tick, flow = group.fed
        if group.plant.flow_mm_s != flow:
            fed_mm, fed_tick, flow = fed_mm + flow * (self.tick - fed_tick) * TICK_S, self.tick, group.plant.flow_mm_s
            group.fed = (fed_mm, fed_tick, flow)
        plan = plan.copy()
        ticks = plan.tick + plan.n_ticks
        plan.e_position_steps = [wrap_s32(math.floor((fed_mm + flow * (int(t) - fed_tick) * TICK_S) * E_STEPS_PER_MM))
                                 for t in ticks]
        plan.flags.writeable = False
        return plan

    def _run_group(self, group: LaneGroup, plan: np.recarray, kinds: tuple, state: LaneState, z: np.ndarray,
                   records: bk.Records) -> None:
        """Every lane of a group over the plan (a radiating plant's lanes in as many rounds as bins need)."""
        def tables_for(g: LaneGroup) -> Tables:
            if g.plant.linear:
                return linear_tables(g.plant.model, g.plant.d, kinds, TICKS_PER_READING)
            assert g.bins is not None  # set by run_group
            return bin_tables(g.plant, g.plant.d, kinds, TICKS_PER_READING, *g.bins)

        kernel = bk.law_kernel(self.law)
        adc_maps = bk.AdcMaps(*self._adc_tables(), _raw_lut(self.lanes.table))
        noise = bk.Noise(self.noise_lsb, self.streams, z)

        def run_part(part: np.ndarray, q_start: np.ndarray, t: Tables, stop: np.ndarray, need: np.ndarray,
                     periods: np.ndarray = plan, probe: bool = False, lane_state: LaneState = state,
                     x: np.ndarray | None = None) -> None:
            fw = self._firmware_constants(t.bin_lo, not group.plant.linear, probe, group.plant.fan)
            scratch = bk.Scratch(np.zeros((2, 2, bk.MAX_PULSES), np.int64), np.zeros((2, group.x.shape[0])),
                                 np.zeros(MAX_SAMPLES), np.zeros(1, BOARD_INPUTS).view(np.recarray))
            kernel(bk.Work(part, group.lanes, q_start, stop, need), periods, _plant_maps(t), adc_maps, fw,
                   bk.Lanes(lane_state.board, self._params, lane_state.state, group.x if x is None else x,
                            lane_state.ring), noise,
                   bk.Score(lane_state.score_i, lane_state.score_f, self._score_array()), records, scratch)

        def run(q_start: np.ndarray, threads: int, **options) -> np.ndarray:
            """Each lane of the group from q_start to the end of ``options["periods"]`` (else the plan)."""
            n_ops = len(options.get("periods", plan))
            return run_group(group, n_ops, self.lanes.target_c, tables_for, functools.partial(run_part, **options),
                             threads, q_start)

        run(self._shared_prefix(group, plan, run, state, records), self.threads)

    def _shared_prefix(self, group: LaneGroup, plan: np.recarray, run: Callable[..., np.ndarray], state: LaneState,
                       records: bk.Records) -> np.ndarray:
        """Each lane's first period to run. Lanes in the same state, on the same noise and with the same
        parameters outside their law's ``tuning`` run the same periods until their controllers first read
        their own tuning (a heat-up at full power, typically): one of them runs those periods, found by a
        probe on a copy of the state, and the others take its state (and records) there."""
        q_start = np.zeros(len(group.lanes), np.int64)
        classes = _alike(self._untuned_keys(group, state))
        if not classes:
            return q_start
        firsts = np.array([members[0] for members in classes])

        def only(lanes: np.ndarray, end: int) -> np.ndarray:
            """A start for the given lanes, the end for the others (they sit out)."""
            return np.where(np.isin(np.arange(len(q_start)), lanes), 0, end)

        stop = run(only(firsts, len(plan)), 1, probe=True, lane_state=state.copy(), x=group.x.copy())
        for q in np.unique(stop[firsts]):
            if q:
                run(only(firsts[stop[firsts] == q], q), 1, periods=plan[:q])
        n_rows = records.temp.shape[1]
        for members in classes:
            q = int(stop[members[0]])
            first, others = group.lanes[members[0]], group.lanes[members[1:]]
            for lane_array in (state.board, state.state, self._ring, self.score_i, self.score_f):
                lane_array[others] = lane_array[first]
            group.x[:, members[1:]] = group.x[:, members[:1]]
            rows = int(plan.row[q]) if q < len(plan) else n_rows
            for record in records:
                record[others, :rows] = record[first, :rows]
            q_start[members] = q
            self.shared_lane_periods += q * len(others)
        return q_start

    def _untuned_keys(self, group: LaneGroup, state: LaneState) -> np.ndarray:
        """Per lane of the group (rows): everything its periods depend on before its controller reads its
        tuning, as bytes."""
        lanes = group.lanes
        noisy = self.noise_lsb[lanes] != 0.0
        columns = [state.board[lanes], state.state[lanes], group.x.T.copy(), self._ring[lanes],
                   self.score_i[lanes], self.score_f[lanes], self.noise_lsb[lanes],
                   np.where(noisy, self.streams[lanes], -1), *(self._params[name][lanes] for name in self.law.untuned)]
        return np.hstack([np.ascontiguousarray(c).view(np.uint8).reshape(len(lanes), -1) for c in columns])

    def _adc_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """edges, slopes, bounds and the thermistor's constants for the kernel's ADC."""
        divider = self.sensor.divider
        edges = adc_table.adc_edges_c(divider)
        interpolation = adc_table.noise_interpolation(divider)
        assert edges is not None and interpolation is not None  # _kernel_sensor: a beta part
        slopes, bounds = interpolation
        part = divider.part
        sensor_p = np.array([part.c1, part.c2, KELVIN_OFFSET, divider.pullup_ohm, float(ADC_COUNTS)])
        return edges, slopes, bounds, sensor_p

    def _score_array(self) -> np.ndarray:
        return self._score_params() if self.score is not None else np.zeros(3)

    def _pack(self) -> np.recarray:
        """The lanes' boards as the kernel's (N,) ``BOARD`` records."""
        lanes = self.lanes
        return _records(bk.BOARD, amount=lanes.amount, count=lanes.count, pins=lanes.pins, temp_q5=lanes.temp_q5,
                        halted=lanes.halted, trip=lanes.trip_code, runaway_state=lanes.runaway_state,
                        runaway_timer_ms=lanes.runaway_timer_ms, watch_target_c=lanes.watch_target_c,
                        watch_next_ms=lanes.watch_next_ms, acc=lanes.adc.acc[0], hint=self._adc_hint,
                        runaway_pending=lanes.runaway_c != lanes.target_c, ring_head=self._ring_state[:, 0],
                        ring_len=self._ring_state[:, 1], n=self.n_lanes)

    def _unpack(self, board: np.recarray) -> None:
        lanes = self.lanes
        lanes.amount, lanes.count, lanes.temp_q5 = board.amount.copy(), board.count.copy(), board.temp_q5.copy()
        lanes.pins, lanes.halted = board.pins.astype(bool), board.halted.astype(bool)
        lanes.trip_code, lanes.runaway_state = board.trip.copy(), board.runaway_state.copy()
        lanes.runaway_timer_ms = board.runaway_timer_ms.copy()
        lanes.watch_target_c, lanes.watch_next_ms = board.watch_target_c.copy(), board.watch_next_ms.copy()
        lanes.adc.acc = [board.acc.copy()]
        self._adc_hint = board.hint.copy()
        self._ring_state = np.column_stack([board.ring_head, board.ring_len])

    def _firmware_constants(self, bin_lo: int, radiating: bool, probe: bool, fan: float) -> np.ndarray:
        """The kernel's ``fw`` record: this run's target and limits, the firmware's constants, the call's
        settings (a radiating plant's first bin, probing) and the part fan the board drives (M106)."""
        lanes = self.lanes
        limits = lanes.temp_range
        return _records(
            bk.FIRMWARE, target_c=lanes.target_c, raw_max=limits.raw_max, raw_min=limits.raw_min,
            mintemp_q5=limits.mintemp_c << TEMP_FRAC_BITS, maxtemp_q5=limits.maxtemp_c << TEMP_FRAC_BITS,
            runaway_period_ms=lanes.runaway_period_ms, runaway_hysteresis_c=lanes.runaway_hysteresis_c,
            watch_increase_c=lanes.watch_increase_c, watch_hysteresis_c=lanes.watch_hysteresis_c,
            watch_period_ms=lanes.watch_period_ms, pwm_period=SOFT_PWM_PERIOD_TICKS, adc_max=ADC_MAX,
            delay=self._delay, bin_lo=bin_lo, radiating=radiating, record=self.record, score=self.score is not None,
            row_base=self._rows, probe=probe, fan_speed=round(FAN_SPEED_MAX * fan), n=1)

    # -- records ------------------------------------------------------------------------------
    def bytes_per_lane(self) -> float:
        """Memory held per lane: plant state, firmware state, constants, dead-time ring, score and records."""
        arrays = [*(g.x for g in self.groups), self._pack(), self._params, self.law.read_state(self.lanes.control),
                  self._ring, self.score_i, self.score_f]
        arrays += [a for chunk in self._chunks for a in chunk[1:]]
        return sum(a.nbytes for a in arrays) / self.n_lanes

    def _column(self, index: int) -> np.ndarray:
        if not self._chunks:
            return np.zeros((0,) if index == 0 else (0, self.n_lanes))
        joined = np.concatenate([chunk[index] for chunk in self._chunks], axis=-1)
        return joined if index == 0 else joined.T

    @property
    def _t_s(self) -> np.ndarray:
        return self._column(0)

    @property
    def _measured_c(self) -> np.ndarray:
        return self._column(1) / TEMP_ONE

    @property
    def _block_c(self) -> np.ndarray:
        return self._column(3)

    @property
    def _sensor_c(self) -> np.ndarray:
        return self._column(4)

    @property
    def _duty(self) -> np.ndarray:
        return self._column(2) / SOFT_PWM_MAX


def run_group(group: LaneGroup, n_ops: int, target_c: float, tables_for: Callable[[LaneGroup], object],
              run_part: Callable[..., None], threads: int, q_start: np.ndarray | None = None) -> np.ndarray:
    """A kernel over every lane of a group, from each lane's start (``q_start``, else the first period)
    to the plan's end, over threads; where each lane stopped (n_ops, or where a probe stopped it).

    A radiating plant's lanes stop where they need a block bin the tables lack (the kernel's ``stop``
    and ``need_bin``): the tables grow to cover it and those lanes go on from where they stopped. The
    first tables reach from the lanes' blocks to ``TARGET_HEADROOM_C`` above the target."""
    n_g = len(group.lanes)
    q_start = np.zeros(n_g, np.int64) if q_start is None else q_start
    stop, need = q_start.copy(), np.zeros(n_g, np.int64)
    todo = np.flatnonzero(q_start < n_ops)
    if not group.plant.linear:
        lti = group.plant.model.lti
        blocks = lti.c[BLOCK] @ group.x + lti.f[BLOCK] @ group.plant.d
        wanted = np.append([block_bin(float(b)) for b in blocks], block_bin(target_c + TARGET_HEADROOM_C))
        group.bins = _bin_range(wanted, group.bins)
    while todo.size:
        tables = tables_for(group)
        n_parts = max(1, min(threads, len(todo) // MIN_LANES_PER_THREAD))
        parts = np.array_split(todo, n_parts)
        calls = [functools.partial(run_part, part, q_start, tables, stop, need) for part in parts]
        if n_parts == 1:
            calls[0]()
        else:
            list(_pool(n_parts).map(lambda call: call(), calls))
        stopped = todo[(stop[todo] < n_ops) & (need[todo] != bk.PROBED)]
        if stopped.size:
            group.bins = _bin_range(need[stopped], group.bins)
            q_start[stopped] = stop[stopped]
        todo = stopped
    return stop


def _alike(keys: np.ndarray) -> list[np.ndarray]:
    """The classes of two or more equal rows of keys, each as its row numbers (ascending)."""
    classes: dict[bytes, list[int]] = {}
    for row, key in enumerate(keys):
        classes.setdefault(key.tobytes(), []).append(row)
    return [np.array(rows) for rows in classes.values() if len(rows) > 1]


def _bin_range(need: np.ndarray, current: tuple[int, int] | None) -> tuple[int, int]:
    """Bins to build: the current ones and every needed one, with BIN_MARGIN more each way."""
    lo, hi = int(np.min(need)) - BIN_MARGIN, int(np.max(need)) + BIN_MARGIN
    return (lo, hi) if current is None else (min(lo, current[0]), max(hi, current[1]))


def _plant_maps(t: Tables) -> bk.PlantMaps:
    """A group's tables as the kernel reads them."""
    return bk.PlantMaps(t.px, t.pdd, t.fx, t.fdd, t.sample_rows, *t.chords, t.steps, t.io)


def _records(dtype: np.dtype, n: int, **columns) -> np.recarray:
    """(n,) records of ``dtype`` with every field given (ValueError names a missing or unknown one)."""
    names = set(field_names(dtype))
    if set(columns) != names:
        missing, unknown = names - set(columns), set(columns) - names
        raise ValueError(f"record fields: missing {sorted(missing)}, unknown {sorted(unknown)}")
    out = np.zeros(n, dtype).view(np.recarray)
    for name, values in columns.items():
        out[name] = values
    return out


def _score_lanes(si: np.ndarray, sf: np.ndarray, sp: np.ndarray, row: int, flags: int, temp_c: np.ndarray,
                 duty: np.ndarray) -> None:
    """``batch_kernel.score_row`` on every lane at once (the numpy lanes' reading)."""
    abs_error = np.abs(sp[bk.S_TARGET] - temp_c)
    idle = si[:, bk.HOLDING] == 0
    heat = bool(flags & bk.HEAT)
    start = idle & ((heat & (abs_error <= sp[bk.S_BAND])) | bool(flags & bk.LAST_HEAT))
    si[start, bk.REACHED] = heat & (abs_error[start] <= sp[bk.S_BAND])
    si[start, bk.HOLDING], si[start, bk.FIRST_ROW] = 1, row
    if heat:
        sf[:, bk.MAX_BEYOND] = np.maximum(sf[:, bk.MAX_BEYOND], -sp[bk.S_SIGN] * (sp[bk.S_TARGET] - temp_c))
    holding = si[:, bk.HOLDING] == 1
    sf[holding, bk.ABS_ERROR_SUM] += abs_error[holding]
    stepping = holding & (si[:, bk.HOLD_ROWS] > 0)
    sf[stepping, bk.DUTY_STEP_SUM] += np.abs(duty - sf[:, bk.PREV_DUTY])[stepping]
    si[holding, bk.HOLD_ROWS] += 1
    sf[:, bk.PREV_DUTY] = duty


def _n_samples(row: np.record) -> int:
    """ADC samples in one plan row's period."""
    n, s0 = int(row.n_ticks), int(row.first_sample)
    return len(range(s0, n, MIN_ADC_ISR_LOOPS))


def _dot(rows: np.ndarray, x: np.ndarray) -> np.ndarray:
    """rows (J, n_x) times x (n_x, N), summed over n_x in index order (as the kernel does)."""
    out = rows[:, 0, None] * x[0]
    for i in range(1, x.shape[0]):
        out = out + rows[:, i, None] * x[i]
    return out


def _output(row: np.ndarray, x: np.ndarray) -> np.ndarray:
    """row[:n_x] . x + row[n_x] on every lane, as the kernel's ``output``."""
    return _dot(row[None, :-1], x)[0] + row[-1]


@functools.lru_cache(maxsize=64)
def _clock_plan(phase: int, temp_count: int, pwm_count: int, tick: int, stop: int) -> tuple:
    """The shared clock's periods from ``tick`` to ``stop``: (plan (P,) ``PLAN`` records, kinds, end state).

    Each period runs to the next reading (or to ``stop``), as the numpy path's ``_period``;
    a kind is one (length, sample offsets) pair. End state: ADC phase, temp_count, PWM count.
    """
    adc = AdcSequencer(1, port=None)
    adc.phase, adc.temp_count = phase, temp_count
    rows: list[tuple[int, ...]] = []
    kinds: dict[tuple[int, tuple[int, ...]], int] = {}
    n_read = z_first = 0
    while tick < stop:
        to_reading = adc.ticks_to_reading()
        n = min(stop - tick, to_reading)
        offsets = adc.sample_offsets(n)[0]
        kind = kinds.setdefault((n, tuple(offsets)), len(kinds))
        adc.skip(n, [[0] * len(offsets)])
        adc.raw_ready = False
        reading = int(n == to_reading)
        first_wrap = (SOFT_PWM_PERIOD_TICKS - pwm_count) % SOFT_PWM_PERIOD_TICKS
        last = (pwm_count + n - 1) % SOFT_PWM_PERIOD_TICKS
        rows.append((n, offsets.start, reading, pwm_count, ticks_to_ms(tick + n), kind, tick, n_read, 0, z_first,
                     first_wrap, last, 0))
        n_read += reading
        z_first += len(offsets)
        tick += n
        pwm_count = last + 1
    plan = np.array(rows, np.int64).reshape(-1, len(field_names(bk.PLAN))).view(bk.PLAN)[:, 0].view(np.recarray)
    plan.flags.writeable = False
    return plan, tuple(kinds), (adc.phase, adc.temp_count, pwm_count)


@functools.lru_cache(maxsize=8)
def _raw_lut(table: TempTable) -> np.ndarray:
    """``lookup_q5`` of every raw value the ADC can sum, for the kernel to index."""
    return lookup_q5(table, np.arange(MAX_RAW_THERMISTOR_VALUE + 1))
