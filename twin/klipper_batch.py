"""Klipper batches: N Klipper heaters as lanes of one clock, each a ``KlipperTwin`` with one heater.

The Klipper loop of a tuner: every lane is Klipper's host PID (``ControlPID`` and ``set_pwm``),
``verify_heater``, the MCU's ADC with its range check and its soft PWM, on its own plant (lanes
given the same plant object share it) with its own gains and its own ADC noise
(``HeaterSetup.noise_lsb``); all lanes run the same heater configuration otherwise. ``twin.klipper_kernel``
runs them (compiled with numba, else as plain Python), spread over threads; a lane equals
``KlipperTwin([setup], seed=seed)`` to float rounding (tests/twin/test_klipper_batch.py): Klipper's host
computes in float, so does the kernel, in the same order, and the plant agrees with the scalar twin's
to rounding.

Kalico's control: pid computes exactly what Klipper's does (firmware_port/kalico), so Kalico lanes are these
lanes with Kalico's PWM rules: setups built with ``kalico_extruder_setup`` (a ``KalicoHeaterConfig``) run its
absolute 0.05 change threshold and its lost_update_tolerance resend margin. pid_v and mpc run on
``KlipperTwin`` only.

Noise: ``seed`` for every lane or per lane (None: KlipperTwin's default, 0). Common random numbers
(twin/lane_noise.py): lanes that name the same seed draw the same normal sequence, scaled by their own
noise_lsb, and it is the one ``KlipperTwin([setup], seed=seed)``'s heater draws (SAMPLE_COUNT normals
per MCU report, in order). So a lane with seed s and noise n reads what that scalar twin reads.

    setup = dataclasses.replace(extruder_setup(plant), noise_lsb=1.0)
    batch = KlipperBatch(gains_setups(setup, gains), seed=[1, 1, 2])     # three lanes, two noise draws
    batch.set_target(210.0)
    batch.schedule(300.0, lambda b: [p.set_inputs(1.0, 0.0, 25.0) for p in b.plants])
    batch.run_until(900.0)
    batch.result().hotend.measured_c        # (reports, lanes): what Stats prints as temp

Not modelled, as in ``KlipperTwin`` with one heater: the Stats lines and the klippy.log text (use
``KlipperTwin`` for those), and the main-thread watchdog, which never fires while ``stats()`` runs
every second (it forces the PWM to 0 only 5 s after the last call; a halted lane sends nothing).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence

import numpy as np

from firmware_port.klipper import CommandError, HeaterConfig, VerifyHeater
from firmware_port.klipper.heater import PWM_RESEND_2025_08, REPORT_TIME, SAMPLE_COUNT, \
    SAMPLE_TIME
from firmware_port.klipper.verify_heater import CHECK_INTERVAL_S
from firmware_port.thermistor import KELVIN_OFFSET, SteinhartHart
from twin import adc_table, batch_kernel as bk, klipper_kernel as kk
from twin.batch import LaneGroup, lane_threads, run_group
from twin.clock import TICK_S, EventQueue, tick_near
from twin.klipper_twin import ADC_FIRST_SAMPLE_S, PRIO_ADC, PRIO_REPORT, PRIO_USER, PRIO_VERIFY, RANGE_CHECK_COUNT, \
    STM32F103, HeaterSetup, Mcu, calc_adc, calc_temp, host_heater
from twin.lane_noise import draw, noise_levels, seed_streams
from twin.lane_tables import Tables, bin_tables, linear_tables
from twin.limits import DURATION_MAX_S, check_trace_bytes, checked
from twin.result import RunResult
from twin.streaming import ScoreSpec, ScoreTotals

INTERVALS = kk.MAX_INTERVALS
KLIPPER_HOTTEST_C = 3000.0  # a 12-bit converter still counts 1 at 1000 C: its bisection's hot end
DEFAULT_SEED = 0  # KlipperTwin's
# A record row's memory: per lane the reading, duty, sensor and block (float64); per row its time and target.
RECORD_LANE_BYTES, RECORD_ROW_BYTES = 32, 16


def _config_without_gains(config: HeaterConfig) -> HeaterConfig:
    return dataclasses.replace(config, pid_kp=0.0, pid_ki=0.0, pid_kd=0.0)


@functools.lru_cache(maxsize=8)
def _converter(part, pullup_ohm: float, adc_bits: int) -> tuple[np.ndarray, np.ndarray]:
    """The MCU's ADC as switching temperatures (``floor(2^bits R / (R + Rp))``, capped) and the host's
    ``calc_temp`` of every sum of SAMPLE_COUNT conversions."""
    adc_max = (1 << adc_bits) - 1
    scale = float(1 << adc_bits)

    def count(temps_c: np.ndarray) -> np.ndarray:
        return np.minimum(np.floor(calc_adc(part, pullup_ohm, temps_c) * scale), adc_max)

    edges = adc_table.edges_of(count, adc_max, KLIPPER_HOTTEST_C)
    inv_max = 1.0 / (SAMPLE_COUNT * adc_max)
    temps = np.array([calc_temp(part, pullup_ohm, v * inv_max) for v in range(SAMPLE_COUNT * adc_max + 1)])
    temps.flags.writeable = False
    return edges, temps


def _sensor_params(part: SteinhartHart, pullup_ohm: float, adc_bits: int) -> np.ndarray:
    """The kernel's ``sensor_p``: a noisy conversion's analog value as ``calc_adc`` computes it (p^3 / 27 of
    ``resistance_ohm``'s Cardano formula taken here, as there, in Python's float)."""
    p27 = (part.c2 / part.c3) ** 3 / 27.0 if part.c3 else 0.0
    sp = np.zeros(kk.N_SP)
    sp[[kk.SP_C1, kk.SP_C2, kk.SP_C3, kk.SP_P27, kk.SP_KELVIN, kk.SP_PULLUP, kk.SP_SCALE]] = (
        part.c1, part.c2, part.c3, p27, KELVIN_OFFSET, pullup_ohm, float(1 << adc_bits))
    return sp


@functools.lru_cache(maxsize=64)
def _schedule(first_sample_s: float, verify: bool, after: tuple[float, int], until: tuple[float, int]) -> list:
    """KlipperTwin's heater events in its order (time, then priority) from after ``after`` up to and
    including ``until`` ((time, priority) pairs): (time, priority, op, window k)."""
    ops = []
    k = max(0, math.floor((after[0] - first_sample_s) / REPORT_TIME) - 1)
    while True:
        first_s = first_sample_s + k * REPORT_TIME
        if (first_s, PRIO_ADC) > until:
            break
        for time_s, prio, op in ((first_s, PRIO_ADC, kk.ADC), (first_s + SAMPLE_COUNT * SAMPLE_TIME, PRIO_REPORT,
                                                                 kk.REPORT)):
            if after < (time_s, prio) <= until:
                ops.append((time_s, prio, op, k))
        k += 1
    if verify:
        v = float(max(0, math.floor(after[0])))
        while (v, PRIO_VERIFY) <= until:
            if (v, PRIO_VERIFY) > after:
                ops.append((v, PRIO_VERIFY, kk.VERIFY, -1))
            v += CHECK_INTERVAL_S
    return sorted(ops)


@functools.lru_cache(maxsize=64)
def _plan(first_sample_s: float, verify: bool, after: tuple[float, int], until: tuple[float, int], tick: int,
          advance_to: int | None) -> tuple:
    """The kernel's plan of the heater events after ``after`` up to ``until`` (``_schedule``) with the
    plants at ``tick``: (plan, its times, the windows' tick offsets, the run kinds (the plants' runs
    from one ADC window or scenario event to the next) and window kinds, the report times, the last
    event's (time, priority), the plants' tick after)."""
    ops = _schedule(first_sample_s, verify, after, until)
    rows: list[tuple[int, ...]] = []
    times: list[tuple[float, float]] = []
    windows: dict[tuple[int, ...], int] = {}
    runs: dict[int, int] = {}
    for time_s, _, op, _ in ops:
        start = run_kind = window = -1
        last_s = math.nan
        if op == kk.ADC:
            start = tick_near(time_s)
            read_time = time_s + SAMPLE_COUNT * SAMPLE_TIME
            offs = tuple(tick_near(time_s + i * SAMPLE_TIME) - start for i in range(SAMPLE_COUNT))
            offs += (tick_near(read_time) - start,)
            window = windows.setdefault(offs, len(windows))
            run_kind = runs.setdefault(start - tick, len(runs))
            last_s = time_s + (SAMPLE_COUNT - 1) * SAMPLE_TIME
            tick = start
        rows.append((op, start, run_kind, window, 0, 0))
        times.append((time_s, last_s))
    if advance_to is not None and advance_to > tick:
        rows.append((kk.ADVANCE, advance_to, runs.setdefault(advance_to - tick, len(runs)), -1, 0, 0))
        times.append((math.nan, math.nan))
        tick = advance_to
    plan = np.array(rows, np.int64).reshape(-1, kk.PLAN_COLUMNS)
    plan_t = np.array(times, float).reshape(-1, 2)
    is_report, is_adc = plan[:, kk.OP] == kk.REPORT, plan[:, kk.OP] == kk.ADC
    plan[is_report, kk.ROW] = np.arange(int(is_report.sum()))
    plan[is_adc, kk.ROW] = SAMPLE_COUNT * np.arange(int(is_adc.sum()))  # each window's first noise draw
    for array in (plan, plan_t):
        array.flags.writeable = False  # shared by the runs that replay it; the kernel reads it only
    kinds = (tuple((n, ()) for n in runs), tuple((0, offs) for offs in windows))
    done = ops[-1][:2] if ops else after
    return plan, plan_t, list(windows), kinds, plan_t[is_report, 0], done, tick


class KlipperBatch:
    """N single-heater Klipper printers on one clock; ``run_until``, then ``result()`` or ``score_totals()``."""

    def __init__(self, setups: Sequence[HeaterSetup], *, mcu: Mcu = STM32F103, seed: int | Sequence[int] | None = None,
                 record: bool = True, score: ScoreSpec | None = None, threads: int | None = None):
        if not setups:
            raise ValueError("a batch needs at least one lane")
        self._check(setups)
        first = setups[0]
        self.setup, self.mcu, self.n_lanes = first, mcu, len(setups)
        self.noise_lsb = noise_levels([s.noise_lsb for s in setups], self.n_lanes)
        self.streams, self._generators = seed_streams(DEFAULT_SEED if seed is None else seed, self.n_lanes)
        self.record, self.score = record, score
        self.threads = lane_threads(threads)
        self.heaters = [host_heater(s.config) for s in setups]
        self.groups = self._group([s.plant for s in setups])
        self.first_sample_s = ADC_FIRST_SAMPLE_S  # the heater's query slot: the first and only one
        self.edges, self.temps = _converter(first.part, first.pullup_ohm, mcu.adc_bits)
        self.sensor_p = _sensor_params(first.part, first.pullup_ohm, mcu.adc_bits)
        self.cfg = self._settings(first)
        self.gains = np.array([[h.control.kp, h.control.ki, h.control.kd, h.control.temp_integ_max]  # type: ignore[attr-defined]
                               for h in self.heaters])
        self._state()
        self.time_s = 0.0
        self._done: tuple[float, int] = (-1.0, -1)  # the last event run: (time, priority)
        self._plant_tick = 0
        self._events = EventQueue()
        self._rows = 0
        self._t_s: list[np.ndarray] = []
        self._chunks: list[tuple] = []  # (temp, duty, sensor, block) (N, rows) per stretch
        self._targets: list[float] = []

    @staticmethod
    def _check(setups: Sequence[HeaterSetup]) -> None:
        first = setups[0]
        for lane, s in enumerate(setups):
            if s.config.control != "pid":
                raise ValueError(f"lane {lane}: a Klipper batch runs control: pid, not {s.config.control!r}")
            same = (_config_without_gains(s.config), s.sensor, s.pullup_ohm, s.pwm_cycle_time_s, s.verify)
            if same != (_config_without_gains(first.config), first.sensor, first.pullup_ohm, first.pwm_cycle_time_s,
                        first.verify):
                raise ValueError(f"lane {lane}: every lane needs lane 0's heater settings but its PID gains")
            if s.plant.delay_ticks != first.plant.delay_ticks:
                raise ValueError("every lane's plant needs the same dead time")

    def _group(self, plants: list) -> list[LaneGroup]:
        groups: dict[int, list[int]] = {}
        for lane, p in enumerate(plants):
            groups.setdefault(id(p), []).append(lane)
        return [LaneGroup(plants[lanes[0]], np.array(lanes, np.int64), np.repeat(plants[lanes[0]].x[:, None], len(lanes),
                                                                               axis=1)) for lanes in groups.values()]

    def _settings(self, setup: HeaterSetup) -> np.ndarray:
        heater = self.heaters[0]
        part, pullup, mcu = setup.part, setup.pullup_ohm, self.mcu
        max_sum = SAMPLE_COUNT * mcu.adc_max
        low, high = sorted(calc_adc(part, pullup, t) for t in (heater.min_temp, heater.max_temp))
        verify = VerifyHeater(heater, **(setup.verify or {}))
        cycle_ticks = int(setup.pwm_cycle_time_s * mcu.clock_hz)  # mcu.py seconds_to_clock
        delay = setup.plant.delay_ticks
        cfg = np.zeros(kk.N_CFG)
        for index, value in {
            kk.C_MAX_POWER: heater.max_power, kk.C_INV_SMOOTH: heater.inv_smooth_time, kk.C_SMOOTH: heater.smooth_time,
            kk.C_PWM_DELAY: heater.pwm_delay, kk.C_MIN_PWM_CHANGE: heater.min_pwm_change,
            kk.C_MAX_HEAT: heater.max_heat_time, kk.C_RESEND_2025_08: heater.config.pwm_resend == PWM_RESEND_2025_08,
            kk.C_LOST_REPORTS: heater.lost_reports,
            kk.C_CYCLE_S: cycle_ticks / mcu.clock_hz, kk.C_CYCLE_TICKS: cycle_ticks, kk.C_CLOCK_HZ: mcu.clock_hz,
            kk.C_MIN_SUM: max(0, min(0xFFFF, int(low * max_sum))),
            kk.C_MAX_SUM: max(0, min(0xFFFF, math.ceil(high * max_sum))), kk.C_RANGE_COUNT: RANGE_CHECK_COUNT,
            kk.C_V_HYST: verify.hysteresis, kk.C_V_MAX_ERROR: verify.max_error, kk.C_V_GAIN: verify.heating_gain,
            kk.C_V_GAIN_TIME: verify.check_gain_time, kk.C_STALE_S: heater.quell_stale_time, kk.C_TICK_S: TICK_S,
            kk.C_DELAY: delay, kk.C_ADC_MAX: mcu.adc_max, kk.C_RECORD: self.record, kk.C_SCORE: self.score is not None,
        }.items():
            cfg[index] = value
        # every PWM value the plant may still see: the dead time's worth of reports, and a few pending
        self._segment_cap = int(delay * TICK_S / REPORT_TIME) + 8
        return cfg

    def _state(self) -> None:
        n = self.n_lanes
        heater, control = self.heaters[0], self.heaters[0].control
        self.kstate = np.zeros((n, kk.N_K), np.int64)
        self.kstate[:, kk.SEG_LEN] = 1  # SoftPwm starts with the pin off from time 0
        self.kstate[:, kk.HINT] = self.mcu.adc_max
        self.fstate = np.zeros((n, kk.N_F))
        for column, value in {kk.LAST_TEMP: heater.last_temp, kk.SMOOTHED: heater.smoothed_temp,
                              kk.LAST_TEMP_TIME: heater.last_temp_time, kk.LAST_PWM: heater.last_pwm_value,
                              kk.NEXT_PWM_TIME: heater.next_pwm_time, kk.PREV_TEMP: control.prev_temp,  # type: ignore[attr-defined]
                              kk.PREV_TEMP_TIME: control.prev_temp_time, kk.PREV_DERIV: control.prev_temp_deriv,  # type: ignore[attr-defined]
                              kk.PREV_INTEG: control.prev_temp_integ, kk.V_GOAL_TIME: math.inf,  # type: ignore[attr-defined]
                              kk.SHUTDOWN_AT: math.nan}.items():
            self.fstate[:, column] = value
        self.segments = np.zeros((n, self._segment_cap, 2))
        self.score_i = np.zeros((n, bk.N_SCORE), np.int64)
        self.score_f = np.zeros((n, bk.N_SCORE))
        self.score_f[:, bk.MAX_BEYOND] = -np.inf
        self._first_s: float | None = None

    # -- the outside world ---------------------------------------------------------------------------
    @property
    def plants(self) -> list:
        """The distinct plants (one per group of lanes): a scenario's events act on each."""
        return [g.plant for g in self.groups]

    @property
    def halted(self) -> np.ndarray:
        """Per lane: shut down (verify_heater or the ADC range check)."""
        return self.kstate[:, kk.HALTED].astype(bool)

    @property
    def target_c(self) -> float:
        return float(self.cfg[kk.C_TARGET])

    def set_target(self, temp_c: float) -> None:
        """SET_HEATER_TEMPERATURE on every lane (CommandError out of range, as Klipper)."""
        checked("temp_c", temp_c)  # Klipper's range check lets NaN through: full power
        self.heaters[0].set_target(temp_c)
        self.cfg[kk.C_TARGET] = temp_c

    def schedule(self, at_s: float, action: Callable[[KlipperBatch], None]) -> None:
        """Run ``action(batch)`` at at_s, before the heater events due then; each plant first runs to the
        tick nearest at_s (as KlipperTwin's scenario events do)."""
        checked("at_s", at_s, 0.0, DURATION_MAX_S, "s")
        if at_s < self.time_s:
            raise ValueError(f"cannot schedule at {at_s} s: the batch is at {self.time_s} s")
        self._events.push(at_s, action, self)

    def run_until(self, t_s: float) -> None:
        """Advance to t_s seconds, running every event due up to and including it (at most DURATION_MAX_S;
        ValueError if the records would outgrow memory)."""
        checked("t_s", t_s, 0.0, DURATION_MAX_S, "s")
        if self.record:
            check_trace_bytes(t_s, t_s / REPORT_TIME * (RECORD_LANE_BYTES * self.n_lanes + RECORD_ROW_BYTES),
                              "keep no trace (record=False, score=ScoreSpec(...)), run fewer lanes or run shorter")
        if t_s < self.time_s:
            raise ValueError(f"cannot run back to {t_s} s from {self.time_s} s")
        while (due := self._events.next_at()) is not None and due <= t_s:
            self._run((due, PRIO_USER - 1), advance_to=tick_near(due))
            for time_s, action, args in self._events.pop_due(due):
                self.time_s = time_s
                action(*args)
        self._run((t_s, PRIO_VERIFY + 1))
        self.time_s = t_s

    def result(self) -> RunResult:
        """The reports of every lane (rows, lanes): target, the raw reading (what Stats prints) as
        measured_c, the duty in force, the true sensor and block temperatures at the report; a
        halted lane holds its last report."""
        if not self.record:
            raise ValueError("this batch keeps no trace (record=False): read score_totals()")
        t_s = np.concatenate(self._t_s) if self._t_s else np.zeros(0)
        temp, duty, sensor, block = (np.concatenate([c[i] for c in self._chunks], axis=1).T if self._chunks
                                     else np.zeros((0, self.n_lanes)) for i in range(4))
        target = np.repeat(np.array(self._targets)[:, None], self.n_lanes, axis=1).reshape(len(t_s), -1)
        hotend = {"target_c": target, "measured_c": temp, "block_c": block, "sensor_c": sensor, "duty": duty}
        return RunResult.from_columns(t_s, {"hotend": hotend}, label=f"klipper, {self.n_lanes} lanes")

    def score_totals(self) -> ScoreTotals:
        """The heater objective's inputs accumulated so far (twin/streaming.py)."""
        if self.score is None or self._first_s is None or self.time_s < self.score.heatup_end_s:
            raise ValueError("score_totals needs score=ScoreSpec(...) and a run past the heat-up's end")
        si, sf = self.score_i, self.score_f
        return ScoreTotals(self._first_s, self._report_times(si[:, bk.FIRST_ROW]), si[:, bk.REACHED].astype(bool),
                           sf[:, bk.MAX_BEYOND].copy(), sf[:, bk.ABS_ERROR_SUM].copy(), si[:, bk.HOLD_ROWS].copy(),
                           sf[:, bk.DUTY_STEP_SUM].copy())

    def bytes_per_lane(self) -> float:
        arrays = [*(g.x for g in self.groups), self.kstate, self.fstate, self.segments, self.gains, self.score_i,
                  self.score_f, *(a for chunk in self._chunks for a in chunk)]
        return sum(a.nbytes for a in arrays) / self.n_lanes

    # -- running ---------------------------------------------------------------------------------
    def _report_times(self, rows: np.ndarray) -> np.ndarray:
        """The read time of report rows (window k = row: the heater reports from its first window on)."""
        first = self.first_sample_s + np.asarray(rows, np.int64) * REPORT_TIME
        return first + SAMPLE_COUNT * SAMPLE_TIME

    def _run(self, until: tuple[float, int], advance_to: int | None = None) -> None:
        """Every heater event after the last one run up to ``until``, then (a scenario event's) the
        plants' run to ``advance_to``."""
        plan, plan_t, offsets, kinds, report_t, self._done, self._plant_tick = _plan(
            self.first_sample_s, self.setup.verify is not None, self._done, until, self._plant_tick, advance_to)
        if not len(plan):
            return
        rows = self._rows + np.arange(len(report_t))
        if self.score is not None and len(report_t) and self._first_s is None:
            self._first_s = float(self._report_times(np.array([self.score.skip_rows]))[0])
        if self.score is not None:
            plan = plan.copy()
            plan[plan[:, kk.OP] == kk.REPORT, kk.FLAGS] = self.score.flags(report_t, self._report_times(rows + 1), rows)
            plan.flags.writeable = False
        records = tuple(np.zeros((self.n_lanes, len(report_t) if self.record else 0)) for _ in range(4))
        n_draws = SAMPLE_COUNT * int((plan[:, kk.OP] == kk.ADC).sum())
        z = draw(self._generators, n_draws) if self.noise_lsb.any() else np.zeros((1, 1))
        self.cfg[kk.C_ROW_BASE] = self._rows
        n_offsets = np.array([len(o) for o in offsets], np.int64)
        offsets_a = np.zeros((max(1, len(offsets)), max(1, *n_offsets)), np.int64)
        for w, offs in enumerate(offsets):
            offsets_a[w, :len(offs)] = offs
        for group in self.groups:
            self._run_group(group, plan, plan_t, offsets_a, n_offsets, kinds, z, records)
        if len(report_t):
            self._t_s.append(report_t)
            self._targets.extend([self.target_c] * len(report_t))
            if self.record:
                self._chunks.append(records)
        self._rows += len(report_t)

    def _run_group(self, group: LaneGroup, plan: np.ndarray, plan_t: np.ndarray, offsets: np.ndarray,
                   n_offsets: np.ndarray, kinds: tuple, z: np.ndarray, records: tuple) -> None:
        run_kinds, window_kinds = kinds
        n_max = max(max(n for n, _ in run_kinds), int(offsets.max())) + 1

        def tables_for(g: LaneGroup) -> tuple[Tables, Tables]:
            if g.plant.linear:
                return linear_tables(g.plant.model, g.plant.d, run_kinds, n_max), \
                    linear_tables(g.plant.model, g.plant.d, window_kinds or ((0, ()),), n_max)
            assert g.bins is not None
            return bin_tables(g.plant, g.plant.d, run_kinds, n_max, *g.bins), \
                bin_tables(g.plant, g.plant.d, window_kinds or ((0, ()),), n_max, *g.bins)

        def run_part(part: np.ndarray, q_start: np.ndarray, tables: tuple[Tables, Tables], stop: np.ndarray,
                     need: np.ndarray) -> None:
            runs, windows = tables
            cfg = self.cfg.copy()
            cfg[kk.C_BIN_LO], cfg[kk.C_RADIATING] = runs.bin_lo, not group.plant.linear
            kk.run_lanes(part, group.lanes, q_start, plan, plan_t, offsets, n_offsets, runs.fx, runs.fdd, windows.px,
                         windows.pdd, windows.bx, windows.bdd, runs.steps, runs.sensor_steps, runs.block_steps,
                         runs.io, self.edges, self.temps, self.sensor_p, cfg, self.gains, self.kstate, self.fstate,
                         self.segments, group.x, self.noise_lsb, self.streams, z, self.score_i, self.score_f,
                         self._score_array(), *records,
                         np.zeros((INTERVALS, 2)), np.zeros((2, group.x.shape[0])), stop, need)

        run_group(group, len(plan), self.target_c, tables_for, run_part, self.threads)

    def _score_array(self) -> np.ndarray:
        spec = self.score
        return np.zeros(3) if spec is None else np.array([spec.target_c, spec.sign, spec.band_c])


def gains_setups(setup: HeaterSetup, gains: np.ndarray | Sequence[Sequence[float]], plants: Sequence | None = None,
                 ) -> list[HeaterSetup]:
    """One setup per row of gains (Kp, Ki, Kd on Klipper's 0..255 scale), on ``setup``'s plant or one per lane."""
    gains = np.atleast_2d(np.asarray(gains, float))
    plants = [setup.plant] * len(gains) if plants is None else list(plants)
    if len(plants) != len(gains):
        raise ValueError(f"plants: one per row of gains ({len(gains)}), not {len(plants)}")
    return [dataclasses.replace(setup, plant=plant, config=dataclasses.replace(setup.config, pid_kp=float(kp),
                                                                                pid_ki=float(ki), pid_kd=float(kd)))
            for (kp, ki, kd), plant in zip(gains, plants)]


__all__ = ["CommandError", "KlipperBatch", "gains_setups"]
