"""Batch twins: N hotend twins advanced together as numpy lanes (N candidate gain sets).

Every lane has the same plant model, scenario and clock and its own PID gains; the firmware
runs vectorised (``firmware_port.marlin.lanes``) and the plant's exact per-tick maps act on all
lanes at once. A tuner evaluates a whole population in one run; tests/test_engine.py keeps each
lane equal to a scalar ``Twin``.

Two implementations of the stretch between scenario events, equal bit for bit
(tests/test_lanes.py): period by period on numpy lanes, or ``twin.batch_kernel``'s compiled
loop over lanes and periods (``kernel="numba"``, the default when numba is installed). The shared
clock (ADC phase, soft-PWM counter, millis) is planned once per stretch and cached, so a tuner
that replays the same scenario each generation pays only for the lanes. A noisy or faulted
sensor chain always takes the numpy path (its conversions draw from the chain's generator).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import numpy as np

from firmware_port.controller import Tunable
from firmware_port.marlin.adc import AdcSequencer
from firmware_port.marlin.constants import MIN_ADC_ISR_LOOPS, SOFT_PWM_MAX, SOFT_PWM_PERIOD_TICKS, \
    TICKS_PER_READING, ticks_to_ms
from firmware_port.marlin.lanes import HotendLanes, lookup_q5
from firmware_port.marlin.pid import (
    D_FILTER_DIVISOR,
    D_RAW_LIMIT_Q8,
    D_SHIFT,
    FUNCTIONAL_RANGE_Q5,
    I_SHIFT,
    OUT_FRAC_BITS,
    OUT_MAX_Q8,
    P_SHIFT,
    PREV_TEMP_EVERY_SAMPLE,
    PidFixed,
    PidGains,
)
from firmware_port.thermistor import ADC_MAX, MAX_RAW_THERMISTOR_VALUE, TEMP_FRAC_BITS, TEMP_ONE, TempTable
from twin import adc_table, batch_kernel as bk
from twin.clock import TICK_S, EventQueue, ticks_at
from twin.linear import BLOCK, SENSOR, TickModel
from twin.result import RunResult
from twin.sensor import SensorChain

PLAN_COLUMNS = 6  # n ticks, first sample offset, reading, soft-PWM count at start, millis at end, kind


def lane_gains(controllers: Sequence[PidGains | Tunable], prev_temp_mode: str) -> list[PidGains]:
    """Each lane's gains: given directly, or taken from an injected fixed-point PID controller
    (the lanes vectorise exactly that law, so its derivative mode must match the batch's)."""
    gains = []
    for lane, item in enumerate(controllers):
        if isinstance(item, PidGains):
            gains.append(item)
        elif BatchTwin.accepts(item, prev_temp_mode):
            gains.append(item.gains)
        else:
            raise TypeError(f"lane {lane}: a batch runs PidGains or PidFixed controllers with prev_temp_mode "
                            f"{prev_temp_mode!r}, not {item!r}")
    return gains


class BatchTwin:
    """N hotends on one plant model; ``run_until`` then read ``t_s``, ``measured_c``, ``duty`` ...

    Records one row per firmware reading: arrays of shape (rows, N) for the firmware's measured
    temperature, the true block and sensor temperatures and the duty (amount / 127).
    """

    @staticmethod
    def accepts(controller: object, prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE) -> bool:
        """Whether a lane can run this controller: the fixed-point PID the lanes vectorise, in their mode."""
        return isinstance(controller, PidFixed) and controller.prev_temp_mode == prev_temp_mode

    def __init__(self, plant, gains: Sequence[PidGains | Tunable], *, prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE,
                 sensor: SensorChain | None = None, kernel: str | None = None):
        if not plant.linear or plant.delay_ticks:
            raise ValueError("batch twins need a linear plant without dead time")
        self.kernel = bk.default_kernel() if kernel is None else kernel
        if self.kernel not in bk.KERNELS:
            raise ValueError(f"kernel={self.kernel!r}: must be one of {', '.join(bk.KERNELS)}")
        self.plant = plant  # the template: model, conditions, disturbances
        self.n_lanes = len(gains)
        self.x = np.repeat(plant.x[:, None], self.n_lanes, axis=1)  # (n_x, N)
        self.sensor = sensor if sensor is not None else SensorChain()
        self.lanes = HotendLanes(lane_gains(gains, prev_temp_mode), prev_temp_mode)
        self.tick = 0
        self._events = EventQueue()
        self._chunks: list[tuple] = []  # records: (t_s (R,), temp_q5, amount, block_c, sensor_c (N, R))
        self._targets: list[int] = []  # the target in force at each row
        self._adc_hint = np.zeros(self.n_lanes, np.int64)  # the kernel's last ADC count: a search start

    def schedule(self, at_s: float, action: Callable[[BatchTwin], None]) -> None:
        """Run ``action(batch)`` at the first tick at or after ``at_s``."""
        self._events.push(ticks_at(at_s), action, self)

    def set_target(self, target_c: int) -> None:
        self.lanes.set_target(target_c)

    def run(self, seconds: float) -> RunResult:
        """Run ``seconds`` more; the result of every lane since time 0 (arrays (rows, lanes))."""
        self.run_until(self.tick * TICK_S + seconds)
        return self.result()

    def result(self, label: str = "batch") -> RunResult:
        n = len(self._targets)
        target = np.repeat(np.array(self._targets, dtype=float)[:, None], self.n_lanes, axis=1).reshape(n, -1)
        hotend = {"target_c": target, "measured_c": self.measured_c, "block_c": self.block_c,
                  "sensor_c": self.sensor_c, "duty": self.duty}
        return RunResult.from_columns(self.t_s, {"hotend": hotend}, label=f"{label}, {self.n_lanes} lanes")

    def run_until(self, t_s: float) -> None:
        end = ticks_at(t_s)
        while self.tick < end:
            for _, action, args in self._events.pop_due(self.tick):
                action(*args)
            due = self._events.next_at()
            stop = end if due is None else min(end, due)
            if stop > self.tick:
                self._run_to(stop)

    def _run_to(self, stop: int) -> None:
        edges = self._adc_edges()
        if self.kernel == "numba" and edges is not None:
            self._run_kernel(stop, edges)
            return
        while self.tick < stop:
            self._period(min(stop - self.tick, self.lanes.adc.ticks_to_reading()), edges)

    def _adc_edges(self) -> np.ndarray | None:
        """The ADC's switching temperatures for a noiseless, healthy chain; None otherwise."""
        if self.sensor.noise_lsb or self.sensor.fault is not None:
            return None
        return adc_table.adc_edges_c(self.sensor.divider)

    # -- numpy lanes, one control period at a time ------------------------------------------
    def _period(self, n: int, edges: np.ndarray | None) -> None:
        """As ``Twin._fast_period``, on all lanes: PWM pulses summed through the step table.

        The float arithmetic is ``batch_kernel``'s, in the same order, so both give the same bits.
        """
        lanes, model, d = self.lanes, self.plant.model, self.plant.d
        offsets = lanes.adc.sample_offsets(n)[0]
        px, pdd, fx, fdd = _period_maps(model, d, n, offsets.start)
        steps, sensor_steps = _step_tables(model)
        pulses = lanes.pulses(n)
        s = np.array(offsets, dtype=np.int64)[:, None]
        sensor_c = _dot(px, self.x) + pdd[:, None]
        for alpha, beta in pulses:
            sensor_c = sensor_c + (sensor_steps[np.maximum(s - alpha, 0)] - sensor_steps[np.maximum(s - beta, 0)])
        if edges is not None:
            samples = adc_table.convert(edges, sensor_c)
        else:
            samples = self.sensor.convert(sensor_c, self.tick + s)
        lanes.skip(n, samples)
        pins_before = lanes.pins.copy()
        reading = lanes.adc.raw_ready
        lanes.task()
        x = _dot(fx, self.x) + fdd[:, None]
        for alpha, beta in pulses:
            x = x + (steps[n - alpha] - steps[n - beta]).T
        # the main loop may have written the pin for the last tick
        self.x = x + model.g[:, None] * (lanes.pins.astype(float) - pins_before)
        self.tick += n
        if reading:
            io = _plant_io(model, d)
            self._targets.append(lanes.target_c)
            self._chunks.append((np.array([self.tick * TICK_S]), lanes.temp_q5[:, None].astype(np.int16),
                                 lanes.amount[:, None].astype(np.int16), _output(io[1], self.x)[:, None],
                                 _output(io[2], self.x)[:, None]))

    # -- the compiled kernel, a whole stretch at once ---------------------------------------
    def _run_kernel(self, stop: int, edges: np.ndarray) -> None:
        lanes, model, d = self.lanes, self.plant.model, self.plant.d
        adc = lanes.adc
        plan, kinds, end = _clock_plan(adc.phase, adc.temp_count, lanes.pwm_count, self.tick, stop)
        tables = _kind_tables(model, d, kinds)
        steps, sensor_steps = _step_tables(model)
        reading = plan[:, 2] == 1
        n_rows = int(reading.sum())
        records = (np.zeros((self.n_lanes, n_rows), np.int16), np.zeros((self.n_lanes, n_rows), np.int16),
                   np.zeros((self.n_lanes, n_rows)), np.zeros((self.n_lanes, n_rows)))
        istate = self._pack()
        bk.run_lanes(plan, *tables, sensor_steps, steps, _plant_io(model, d), edges, _raw_lut(lanes.table),
                     _firmware_constants(lanes), _gains(lanes), istate, self.x, *records,
                     np.zeros((2, bk.MAX_PULSES), np.int64), np.zeros((2, len(self.x))), np.zeros(tables[0].shape[2]))
        self._unpack(istate)
        adc.phase, adc.temp_count, lanes.pwm_count = end
        adc.raw_ready = False
        if n_rows:
            lanes.runaway_c = lanes.target_c
            t_s = (self.tick + np.cumsum(plan[:, 0]))[reading] * TICK_S
            self._chunks.append((t_s, *records))
            self._targets.extend([lanes.target_c] * n_rows)
        lanes.ticks += stop - self.tick
        self.tick = stop

    def _pack(self) -> np.ndarray:
        """The lanes' state as the kernel's (N, N_STATE) int64 matrix."""
        lanes, pid = self.lanes, self.lanes.pid
        columns = {bk.AMOUNT: lanes.amount, bk.COUNT: lanes.count, bk.PINS: lanes.pins, bk.TEMP: lanes.temp_q5,
                   bk.HALTED: lanes.halted, bk.TRIP: lanes.trip_code, bk.R_STATE: lanes.runaway_state,
                   bk.R_TIMER: lanes.runaway_timer_ms, bk.W_TARGET: lanes.watch_target_c,
                   bk.W_NEXT: lanes.watch_next_ms, bk.I_SUM: pid.i_sum_q5, bk.D_TERM: pid.d_term_q8,
                   bk.PREV: pid.prev_q5, bk.RESET: pid.reset_pending, bk.ACC: lanes.adc.acc[0],
                   bk.HINT: self._adc_hint}
        istate = np.zeros((self.n_lanes, bk.N_STATE), np.int64)
        for column, values in columns.items():
            istate[:, column] = np.asarray(values)
        return istate

    def _unpack(self, istate: np.ndarray) -> None:
        lanes, pid = self.lanes, self.lanes.pid
        col = istate.T.copy()
        lanes.amount, lanes.count, lanes.temp_q5 = col[bk.AMOUNT], col[bk.COUNT], col[bk.TEMP]
        lanes.pins, lanes.halted = col[bk.PINS].astype(bool), col[bk.HALTED].astype(bool)
        lanes.trip_code, lanes.runaway_state, lanes.runaway_timer_ms = col[bk.TRIP], col[bk.R_STATE], col[bk.R_TIMER]
        lanes.watch_target_c, lanes.watch_next_ms = col[bk.W_TARGET], col[bk.W_NEXT]
        pid.i_sum_q5, pid.d_term_q8, pid.prev_q5 = col[bk.I_SUM], col[bk.D_TERM], col[bk.PREV]
        pid.reset_pending = col[bk.RESET].astype(bool)
        lanes.adc.acc = [col[bk.ACC]]
        self._adc_hint = col[bk.HINT]

    # -- records ------------------------------------------------------------------------------
    def bytes_per_lane(self) -> float:
        """Memory held per lane: plant state, firmware state, gains and the records so far."""
        arrays = [self.x, self._pack(), _gains(self.lanes)] + [a for chunk in self._chunks for a in chunk[1:]]
        return sum(a.nbytes for a in arrays) / self.n_lanes

    def _column(self, index: int) -> np.ndarray:
        if not self._chunks:
            return np.zeros((0,) if index == 0 else (0, self.n_lanes))
        joined = np.concatenate([chunk[index] for chunk in self._chunks], axis=-1)
        return joined if index == 0 else joined.T

    @property
    def t_s(self) -> np.ndarray:
        return self._column(0)

    @property
    def measured_c(self) -> np.ndarray:
        return self._column(1) / TEMP_ONE

    @property
    def block_c(self) -> np.ndarray:
        return self._column(3)

    @property
    def sensor_c(self) -> np.ndarray:
        return self._column(4)

    @property
    def duty(self) -> np.ndarray:
        return self._column(2) / SOFT_PWM_MAX


def _dot(rows: np.ndarray, x: np.ndarray) -> np.ndarray:
    """rows (J, n_x) times x (n_x, N), summed over n_x in index order (as the kernel does)."""
    out = rows[:, 0, None] * x[0]
    for i in range(1, x.shape[0]):
        out = out + rows[:, i, None] * x[i]
    return out


def _output(row: np.ndarray, x: np.ndarray) -> np.ndarray:
    """row[:n_x] . x + row[n_x] on every lane, as the kernel's ``_output``."""
    return _dot(row[None, :-1], x)[0] + row[-1]


def _period_maps(model: TickModel, d: np.ndarray, n: int, first_sample: int) -> tuple:
    """A run of n ticks sampling the sensor from ``first_sample`` every ADC round: the sensor at
    each sample (px (J, n_x), pdd (J,)) and the end state (fx, fdd) without the heater."""
    px, _, pd, fx, _, fd = model.run_maps(n, tuple(range(first_sample, n, MIN_ADC_ISR_LOOPS)))
    return px[:, SENSOR], pd[:, SENSOR] @ d, fx, fd @ d


def _step_tables(model: TickModel) -> tuple[np.ndarray, np.ndarray]:
    """The heater's step response over up to a period: state (k, n_x) and sensor (k,), k = 0..160."""
    steps = model.u_steps(TICKS_PER_READING)
    return steps, steps @ model.lti.c[SENSOR]


def _plant_io(model: TickModel, d: np.ndarray) -> np.ndarray:
    """(3, n_x + 1): the heater's one-tick response g, then the block and sensor rows with their constant."""
    out_d = model.lti.f @ d
    return np.array([[*model.g, 0.0], [*model.lti.c[BLOCK], out_d[BLOCK]], [*model.lti.c[SENSOR], out_d[SENSOR]]])


def _kind_tables(model: TickModel, d: np.ndarray, kinds: tuple) -> tuple:
    """``_period_maps`` of each kind of period, stacked (samples padded to the longest; px as (n_x, J))."""
    maps = [_period_maps(model, d, n, first) for n, first in kinds]
    n_x, j_max = model.phi.shape[0], max(1, *(len(m[0]) for m in maps))
    px, pdd = np.zeros((len(maps), n_x, j_max)), np.zeros((len(maps), j_max))
    for k, (p, q, _, _) in enumerate(maps):
        px[k, :, : len(p)], pdd[k, : len(q)] = p.T, q
    return px, pdd, np.array([m[2] for m in maps]), np.array([m[3] for m in maps])


@functools.lru_cache(maxsize=64)
def _clock_plan(phase: int, temp_count: int, pwm_count: int, tick: int, stop: int) -> tuple:
    """The shared clock's periods from ``tick`` to ``stop``: (plan (P, 6), kinds, end state).

    Each period runs to the next reading (or to ``stop``), as the numpy path's ``_period``;
    a kind is one (length, first sample offset) pair. End state: ADC phase, temp_count, PWM count.
    """
    adc = AdcSequencer(1, port=None)
    adc.phase, adc.temp_count = phase, temp_count
    rows: list[tuple[int, ...]] = []
    kinds: dict[tuple[int, int], int] = {}
    while tick < stop:
        to_reading = adc.ticks_to_reading()
        n = min(stop - tick, to_reading)
        offsets = adc.sample_offsets(n)[0]
        kind = kinds.setdefault((n, offsets.start), len(kinds))
        adc.skip(n, [[0] * len(offsets)])
        adc.raw_ready = False
        tick += n
        rows.append((n, offsets.start, int(n == to_reading), pwm_count, ticks_to_ms(tick), kind))
        pwm_count = (pwm_count + n - 1) % SOFT_PWM_PERIOD_TICKS + 1
    plan = np.array(rows, np.int64).reshape(-1, PLAN_COLUMNS)
    plan.flags.writeable = False
    return plan, tuple(kinds), (adc.phase, adc.temp_count, pwm_count)


@functools.lru_cache(maxsize=8)
def _raw_lut(table: TempTable) -> np.ndarray:
    """``lookup_q5`` of every raw value the ADC can sum, for the kernel to index."""
    return lookup_q5(table, np.arange(MAX_RAW_THERMISTOR_VALUE + 1))


def _firmware_constants(lanes: HotendLanes) -> np.ndarray:
    """The kernel's ``fw`` vector: this run's target and limits, Marlin's constants."""
    fw = np.zeros(bk.N_FW, np.int64)
    limits = lanes.temp_range
    for index, value in {
        bk.TARGET: lanes.target_c, bk.RUNAWAY_RESET: lanes.runaway_c != lanes.target_c,
        bk.RAW_MAX: limits.raw_max, bk.RAW_MIN: limits.raw_min,
        bk.MINTEMP_Q5: limits.mintemp_c << TEMP_FRAC_BITS, bk.MAXTEMP_Q5: limits.maxtemp_c << TEMP_FRAC_BITS,
        bk.R_PERIOD_MS: lanes.runaway_period_ms, bk.R_HYST_C: lanes.runaway_hysteresis_c,
        bk.W_INC_C: lanes.watch_increase_c, bk.W_HYST_C: lanes.watch_hysteresis_c,
        bk.W_PERIOD_MS: lanes.watch_period_ms, bk.EVERY_SAMPLE: lanes.pid.every_sample,
        bk.P_SHIFT: P_SHIFT, bk.I_SHIFT: I_SHIFT, bk.D_SHIFT: D_SHIFT, bk.D_LIMIT_Q8: D_RAW_LIMIT_Q8,
        bk.D_DIVISOR: D_FILTER_DIVISOR, bk.RANGE_Q5: FUNCTIONAL_RANGE_Q5, bk.OUT_MAX_Q8: OUT_MAX_Q8,
        bk.OUT_FRAC_BITS: OUT_FRAC_BITS, bk.TEMP_FRAC_BITS: TEMP_FRAC_BITS, bk.PWM_PERIOD: SOFT_PWM_PERIOD_TICKS,
        bk.ADC_MAX: ADC_MAX, bk.SAMPLE_EVERY: MIN_ADC_ISR_LOOPS,
    }.items():
        fw[index] = value
    return fw


def _gains(lanes: HotendLanes) -> np.ndarray:
    pid = lanes.pid
    return np.column_stack([pid.kp_q12, pid.ki_q24, pid.kd_q16, pid.i_max_q5]).astype(np.int64)
