"""The benchmark cases of ``python -m tools.bench`` (tools/bench.py, the command, says what each measures):
imported when a benchmark runs, so that the command's ``--help`` loads none of their libraries."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import importlib
import json
import os
import re
import resource
import select
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, TypeVar, cast

import numpy as np
import scipy.optimize
import scipy.signal
import serial

from firmware_port.marlin.constants import SOFT_PWM_PERIOD_TICKS, TICKS_PER_READING
from firmware_port.marlin.pid import PidGains
from protocol.lines import with_checksum
from protocol.printer import BUFSIZE
from firmware_port.firmwares import param_space
from tools.ident.log_fit import HEATER_NAMES
from tools.logs import StatsLog, hardware_logs_dir, load_log
from tools.tuning.evaluate import CHUNK_LANES, KLIPPER_MAX_TEMP_C, Evaluator, preset_problem
from tools.tuning.defaults import DEFAULT_OBJECTIVE
from tools.tuning.objectives import objective, score_spec
from tools.tuning.problems import build_problem, preset_source
from tools.tuning.tuner import DEFAULT_BUDGET, Candidate, tune
from twin import batch_kernel
from twin.batch import THREADS_ENV, BatchTwin, lane_threads
from twin.klipper_batch import KlipperBatch, gains_setups
from twin.klipper_twin import extruder_setup
from twin.build import build_twin
from twin.linear import SENSOR, TICK_S
from twin.plants import ONION_RADIATING_PARAMS, SPECS, TransferFunction, make_plant, respec
from twin.scenario import PRESETS, with_overrides


T = TypeVar("T")


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def bench_single(duration_s: float) -> list[str]:
    scenario = with_overrides(PRESETS["heat_hold"], duration_s=duration_s)
    walls = {}
    for engine in ("fast", "reference"):
        twin = build_twin(scenario, "pid", engine=engine)
        walls[engine] = _timed(functools.partial(twin.run_until, duration_s))
    fast, ref = duration_s / walls["fast"], duration_s / walls["reference"]
    return [
        f"single twin (hotend + bed, pid, {duration_s:g} s heat-and-hold, full ISR fidelity):",
        f"  fast engine      {walls['fast']:8.3f} s wall  {fast:9.0f} x real time",
        f"  reference engine {walls['reference']:8.3f} s wall  {ref:9.0f} x real time",
        f"  fast / reference {walls['reference'] / walls['fast']:8.1f} x",
    ]


def bench_batch(n_lanes: int, duration_s: float, seed: int) -> list[str]:
    rng = np.random.default_rng(seed)
    gains = [PidGains(float(kp), float(ki), float(kd)) for kp, ki, kd in
             zip(rng.uniform(5, 60, n_lanes), rng.uniform(0.2, 5, n_lanes), rng.uniform(10, 200, n_lanes))]
    batch = BatchTwin(make_plant("hotend"), gains)
    batch.schedule(0.0, lambda b: b.set_target(210))
    wall = _timed(lambda: batch.run_until(duration_s))
    periods = n_lanes * len(batch.result().hotend.t_s)
    return [
        f"batch of {n_lanes} hotend twins x {duration_s:g} s, random gains (seed {seed}):",
        f"  wall {wall:.3f} s, {periods / wall:,.0f} firmware control periods per second",
        f"  {n_lanes * duration_s / wall:,.0f} x real time summed over the lanes",
    ]


def bench_open_loop(duration_s: float) -> list[str]:
    """A PWM input at 40 % on the MPC "hotend" preset: engine maps vs lsim on the tick grid."""
    n_ticks = int(round(duration_s / TICK_S))
    u = ((np.arange(n_ticks) % SOFT_PWM_PERIOD_TICKS) < 51).astype(float)
    plant = make_plant("hotend")
    temps = []

    def engine_run():
        for start in range(0, n_ticks, TICKS_PER_READING):
            chunk = u[start : start + TICKS_PER_READING]
            temps.append(plant.outputs(chunk, (0,))[0, SENSOR])
            plant.advance(chunk)

    wall_engine = _timed(engine_run)
    lti = plant.model.lti
    system = scipy.signal.StateSpace(lti.a, np.column_stack([lti.b, lti.e]), lti.c[SENSOR:SENSOR + 1],
                                     np.zeros((1, 2)))
    t = np.arange(n_ticks) * TICK_S
    inputs = np.column_stack([u, np.full(n_ticks, plant.ambient_c)])
    x0 = make_plant("hotend").x
    result: dict[str, np.ndarray] = {}
    wall_lsim = _timed(lambda: result.update(out=scipy.signal.lsim(system, inputs, t, X0=x0, interp=False)[1]))
    lsim_at_chunks = result["out"][::TICKS_PER_READING]
    diff = np.max(np.abs(np.array(temps) - lsim_at_chunks[: len(temps)]))
    return [
        f"open loop, MPC hotend, 40 % PWM for {duration_s:g} s ({n_ticks} ticks):",
        f"  engine {wall_engine:.3f} s, scipy.signal.lsim {wall_lsim:.3f} s, "
        f"lsim / engine {wall_lsim / wall_engine:.1f} x, largest difference {diff:.2e} C",
    ]


TUNE_TARGET_C = 210
TUNE_PRESET = "hotend_cartridge"  # fitted to a real printer (twin/plants.py)
TUNE_BOUNDS = [(1.0, 100.0), (0.01, 10.0), (1.0, 500.0)]  # Kp, Ki /s, Kd s on Marlin's 0..255 scale
SEED000_HORIZON_S, SEED000_POINTS = 50.0, 1000
EVAL_REPEATS = 3  # timed batches of the evaluation cost, after the warm-up; the median is quoted
# Seed 000's Nelder-Mead bounds for its PID on the 5 C/W second-order extruder.
SEED000_BOUNDS = [(0.01, 10.0), (0.001, 1.0), (0.001, 1.0)]


def _timed_value(fn: Callable[[], T]) -> tuple[T, float, float]:
    """fn's value, its wall time and this process's CPU time (what a busy machine inflates less)."""
    start, start_cpu = time.perf_counter(), time.process_time()
    value = fn()
    return value, time.perf_counter() - start, time.process_time() - start_cpu


def _heat_and_hold(plant, gains: list[PidGains], duration_s: float, kernel: str | None = None,
                   streamed: bool = False) -> BatchTwin:
    """A batch heating to the tuning target; ``streamed``: as a tuner runs it (no trace, the heater
    objective's inputs accumulated)."""
    score = score_spec(TUNE_TARGET_C, plant.ambient_c, duration_s / 2, 1) if streamed else None
    batch = BatchTwin(plant, gains, kernel=kernel, record=not streamed, score=score)
    batch.schedule(0.0, lambda b: b.set_target(TUNE_TARGET_C))
    batch.run_until(duration_s)
    return batch


def _random_gains(rng: np.random.Generator, bounds: list[tuple[float, float]], n: int) -> np.ndarray:
    """(n, 3) gains drawn uniformly within bounds."""
    lows, highs = np.array(bounds).T
    return rng.uniform(lows, highs, (n, len(bounds)))


def _seed000_evaluation(kp: float, ki: float, kd: float, t: np.ndarray) -> np.ndarray:
    """Seed 000's loop: its second-order plant under a parallel PID, closed (CG / (1 + CG)), step."""
    plant_num, plant_den = cast(TransferFunction, SPECS["seed000_second"]).polynomials()
    pid_num, pid_den = [kd, kp, ki], [1.0, 0.0]
    closed = scipy.signal.lti(np.polymul(pid_num, plant_num),
                              np.polyadd(np.polymul(pid_den, plant_den), np.polymul(pid_num, plant_num)))
    return scipy.signal.step(closed, T=t)[1]


def bench_evaluation_cost(plant, n_lanes: int, duration_s: float, seed: int, n_seed000: int) -> list[str]:
    """One 600-s evaluation in the batch, as a tuner runs it, against one seed-000 evaluation, measured in this run."""
    rng = np.random.default_rng(seed)
    gains = [PidGains(*map(float, g)) for g in _random_gains(rng, TUNE_BOUNDS, n_lanes)]
    # A tuner's first generation: the kernel loaded from numba's cache (or compiled), the horizon's plan and
    # tables built, the lanes' memory allocated. Then the generations after it: the median of EVAL_REPEATS.
    _, first_s, _ = _timed_value(lambda: _heat_and_hold(plant, gains, duration_s, streamed=True))
    runs = sorted((_timed_value(lambda: _heat_and_hold(plant, gains, duration_s, streamed=True))
                   for _ in range(EVAL_REPEATS)), key=lambda run: run[1])
    batch, wall_s, cpu_s = runs[EVAL_REPEATS // 2]
    wall_numpy_s = _timed(lambda: _heat_and_hold(plant, gains, duration_s, kernel="numpy", streamed=True))
    t = np.linspace(0.0, SEED000_HORIZON_S, SEED000_POINTS)
    seed_gains = _random_gains(rng, SEED000_BOUNDS, n_seed000)
    wall_seed000_s = _timed(lambda: [_seed000_evaluation(kp, ki, kd, t) for kp, ki, kd in seed_gains])
    twin_ms, seed000_ms = wall_s / n_lanes * 1e3, wall_seed000_s / n_seed000 * 1e3
    periods = n_lanes * batch.lanes.ticks // TICKS_PER_READING
    return [
        f"evaluation cost, {n_lanes} lanes of {plant.preset} x {duration_s:g} s, full ISR fidelity, random gains "
        f"(seed {seed}), kernel {batch.kernel} ({batch_kernel.describe()}), {batch.threads} threads, no trace "
        f"(the heater objective streamed); the batch as a tuner's later generations run it (after one warm-up batch: "
        f"{first_s:.3f} s), median of {EVAL_REPEATS}:",
        f"  seed 000 comparison: {twin_ms:.3f} ms per {duration_s:g}-s firmware-in-the-loop evaluation in the batch, "
        f"{seed000_ms:.3f} ms per seed-000 evaluation (scipy.signal.step, {SEED000_HORIZON_S:g} s, "
        f"{SEED000_POINTS} points, mean of {n_seed000}): ratio {seed000_ms / twin_ms:.1f} x (target >= 20)",
        f"  {periods / wall_s:,.0f} firmware control periods per second ({wall_s:.3f} s wall, {cpu_s:.3f} s CPU "
        f"for the batch; numpy lanes {wall_numpy_s:.3f} s, {wall_numpy_s / wall_s:.1f} x slower)",
        f"  {batch.shared_lane_periods / periods:.1%} of the lanes' periods taken from another lane's run (the heat-up "
        f"at full power before the PID band, the same for every lane: run once)",
        f"  memory per lane: {batch.bytes_per_lane() / 1024:.2f} KiB (plant and firmware state, constants and the "
        f"objective's accumulators: no trace, whatever the horizon)",
    ]


USER_LAW_MODULE = "tests.helpers.integer_pi"  # a user's controller with its lane law: its SPACE


def _evaluation_cpu_ms(plant, lanes: list, duration_s: float) -> float:
    """CPU ms per lane of a batch run as a tuner runs it (streamed), median of EVAL_REPEATS after a warm-up."""
    score = score_spec(TUNE_TARGET_C, plant.ambient_c, duration_s / 2, 1)

    def run() -> None:
        batch = BatchTwin(plant, lanes, record=False, score=score)
        batch.set_target(TUNE_TARGET_C)
        batch.run_until(duration_s)

    run()
    return statistics.median(_timed_value(run)[2] for _ in range(EVAL_REPEATS)) / len(lanes) * 1e3


def bench_user_law_cost(plant, n_lanes: int, duration_s: float, seed: int) -> list[str]:
    """A user's integer PI through its own lane law against the built-in PID, CPU per evaluation."""
    try:
        space = importlib.import_module(USER_LAW_MODULE).SPACE
    except ImportError as exc:
        return [f"user lane law: {USER_LAW_MODULE} not importable ({exc}): run from the repository root"]
    rng = np.random.default_rng(seed)
    lows, highs = space.to_search(space.bounds[:, 0]), space.to_search(space.bounds[:, 1])
    pis = [space.make(row) for row in space.from_search(rng.uniform(lows, highs, (n_lanes, space.dims)))]
    pids = [PidGains(*map(float, g)) for g in _random_gains(rng, TUNE_BOUNDS, n_lanes)]
    pid_ms, pi_ms = (_evaluation_cpu_ms(plant, lanes, duration_s) for lanes in (pids, pis))
    return [f"a user's lane law ({USER_LAW_MODULE}: integer PI with back-calculation, random gains), {n_lanes} lanes "
            f"of {plant.preset} x {duration_s:g} s, streamed, CPU ms per evaluation (median of {EVAL_REPEATS}):",
            f"  built-in PID {pid_ms:.3f} ms, user PI {pi_ms:.3f} ms: {pi_ms / pid_ms:.2f} x the PID (target <= 2)"]


def _de(problem, seed: int, popsize: int = 15, generations: int = 100):
    """scipy's differential evolution of a PID problem's three gains with the heater objective, one batch
    per population: (result, evaluations, wall s, CPU s)."""
    evaluate = Evaluator(problem, objective(DEFAULT_OBJECTIVE))
    # tol 0 and atol -1: every generation runs, even when all candidates cost the same (all trip)
    de, wall_s, cpu_s = _timed_value(lambda: scipy.optimize.differential_evolution(
        lambda population: evaluate(population.T), TUNE_BOUNDS, popsize=popsize, maxiter=generations, tol=0.0,
        atol=-1.0, polish=False, vectorized=True, updating="deferred", rng=np.random.default_rng(seed)))
    return de, evaluate.evaluations, wall_s, cpu_s


def bench_de_tune(preset: str, seed: int, popsize: int = 15, generations: int = 100) -> list[str]:
    """scipy's differential evolution on the firmware twin with twin-tune's heater objective on its
    default scenario (heat-up, hold, disturbances), one batch per population."""
    problem = preset_problem(preset, TUNE_TARGET_C)
    _de(problem, seed, popsize, 1)  # the kernels loaded, the scenario's tables built
    de, evaluations, wall_s, cpu_s = _de(problem, seed, popsize, generations)
    kp, ki, kd = de.x
    return [
        f"DE tune of {preset} (3 gains, population {popsize * len(TUNE_BOUNDS)}, {de.nit} generations, "
        f"{evaluations} evaluations of {problem.scenario.duration_s:g} s, objective {DEFAULT_OBJECTIVE}, "
        f"seed {seed}): {wall_s:.3f} s wall (target < 3 s), {cpu_s:.3f} s CPU",
        f"  best Kp {kp:.3f} Ki {ki:.4f} Kd {kd:.2f}: cost {de.fun:.1f}",
    ]


def bench_loop_tunes(preset: str, seed: int) -> list[str]:
    """twin-tune's default tune (rules, the firmware's autotune and defaults, DE with the default budget,
    every candidate on the default ensemble; the proof not included) on the Marlin loop and on the
    Klipper loop, same plant, same run."""
    walls: dict[str, float] = {}
    bests: dict[str, Candidate] = {}
    for loop in ("marlin", "klipper"):
        problem = build_problem(preset_source(preset), TUNE_TARGET_C, loop=loop)
        result, walls[loop], _ = _timed_value(functools.partial(tune, problem, seed=seed))
        bests[loop] = result.best
    ensemble = problem.ensemble.describe().split(";")[0] if problem.ensemble else "none"
    lines = [f"twin-tune's default tune of {preset} at {TUNE_TARGET_C} C (rules, references, DE budget {DEFAULT_BUDGET}, "
             f"seed {seed}; ensemble {ensemble}: each candidate runs once per member), both loops on the batch:"]
    for loop in ("marlin", "klipper"):
        best = bests[loop]
        lines.append(f"  {loop:7s} loop: {walls[loop]:.3f} s wall, best {best.method} "
                     f"Kp {best.params[0]:.2f} Ki {best.params[1]:.3f} Kd {best.params[2]:.1f}: cost {best.cost:.1f}")
    lines.append(f"  klipper / marlin: {walls['klipper'] / walls['marlin']:.2f} x (target <= 3)")
    return lines


def bench_batch_tunes(seed: int) -> list[str]:
    """The DE tune of ``bench_de_tune`` on the paths that ran one twin per candidate before the batch took them."""
    cartridge = preset_problem(TUNE_PRESET, TUNE_TARGET_C)
    problems = {
        "dead time: seed001_fopdt (every Marlin PID trips: full power outside its 10 C band for 20.7 s)":
            preset_problem("seed001_fopdt", TUNE_TARGET_C),
        "dead time: seed003_third (5 s)": preset_problem("seed003_third", TUNE_TARGET_C),
        "radiating loss: hotend_cartridge's radiating fit": dataclasses.replace(
            cartridge, spec=respec(cartridge.spec, ONION_RADIATING_PARAMS)),
        "noisy sensor: hotend_cartridge, 1 LSB, seed 1": dataclasses.replace(cartridge, noise_lsb=1.0, seed=1),
    }
    lines = [f"DE tunes on the batch (population 45, 100 generations, seed {seed}; the first generation's "
             "tables and bins built before the clock starts):"]
    for name, problem in problems.items():
        _de(problem, seed, generations=1)
        de, evaluations, wall_s, cpu_s = _de(problem, seed)
        lines.append(f"  {name}: batched {problem.batched}, {evaluations} evaluations of "
                     f"{problem.scenario.duration_s:g} s, {wall_s:.3f} s wall, {cpu_s:.3f} s CPU, best cost {de.fun:.1f}")
    return lines


def tune_plant():
    """The tuning preset's plant at ambient."""
    return make_plant(TUNE_PRESET)


SERIAL_CLI = [sys.executable, "-m", "tools.cli.serial", "--speed", "max"]
START_TIMEOUT_S = 30  # twin-serial's start: interpreter and imports
REPLY_TIMEOUT_S = 30  # any one answer, M303 included


@contextlib.contextmanager
def _twin_serial_port():
    """twin-serial in its own process and pyserial on its pty, the banner read; both closed after."""
    proc = subprocess.Popen(SERIAL_CLI, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip() if select.select([proc.stdout], [], [], START_TIMEOUT_S)[0] else ""
        if not path:
            proc.terminate()
            raise RuntimeError(f"twin-serial printed no pty path: {proc.communicate()[1].strip()}")
        with serial.Serial(path, 115200, timeout=REPLY_TIMEOUT_S) as port:
            _read_until(port, b"echo:  M304 ")  # the banner's last line
            yield port
    finally:
        proc.terminate()
        proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def _read_until(port: serial.Serial, start: bytes) -> list[bytes]:
    """The lines up to the first that starts with ``start``, that one included."""
    lines: list[bytes] = []
    while not lines or not lines[-1].startswith(start):
        lines.append(port.readline())
        if not lines[-1].endswith(b"\n"):
            raise RuntimeError(f"no line starting with {start!r} within {REPLY_TIMEOUT_S} s")
    return lines


def _round_trips_ms(port: serial.Serial, n: int) -> list[float]:
    times = []
    for _ in range(n):
        start = time.perf_counter()
        port.write(b"M105\n")
        _read_until(port, b"ok")
        times.append((time.perf_counter() - start) * 1000)
    return times


def _stream(port: serial.Serial, n_lines: int, window: int) -> tuple[float, int, int]:
    """Send N1..N<n_lines> (short G1 moves) keeping ``window`` lines unanswered at most;
    the wall time, oks and resends. Numbering starts over with M110 first."""
    port.write(b"M110 N0\n")
    _read_until(port, b"ok")
    lines = [(with_checksum(f"G1 X{100 + n % 2 * 0.5:.1f} Y100 F6000", n) + "\n").encode()
             for n in range(1, n_lines + 1)]
    sent = answered = oks = resends = 0
    start = time.perf_counter()
    while answered < n_lines:
        while sent < n_lines and sent - answered < window:
            port.write(lines[sent])
            sent += 1
        reply = port.readline()
        if not reply.endswith(b"\n"):
            raise RuntimeError(f"no answer within {REPLY_TIMEOUT_S} s after {answered} lines")
        if reply.startswith(b"ok"):
            oks += 1
        elif reply.startswith(b"Resend:"):
            resends += 1
        else:
            continue
        answered += 1
    return time.perf_counter() - start, oks, resends


def bench_protocol(n_requests: int, n_lines: int) -> list[str]:
    with _twin_serial_port() as port:
        trips = _round_trips_ms(port, n_requests)
        streams = {window: _stream(port, n_lines, window) for window in (1, BUFSIZE)}
        start = time.perf_counter()
        port.write(b"M303 E0 S210 C8\n")
        m303 = _read_until(port, b"ok")
        m303_s = time.perf_counter() - start
    gains = [line.decode().split()[-1] for line in m303 if line.startswith(b"#define DEFAULT_K")]
    lines = [
        f"twin-serial on a pty ({' '.join(['python', *SERIAL_CLI[1:]])}), pyserial at 115200 baud:",
        (f"  M105 round trip, {n_requests} requests: median {statistics.median(trips):.3f} ms, "
         f"p99 {statistics.quantiles(trips, n=100)[98]:.3f} ms"),
    ]
    for window, (wall_s, oks, resends) in streams.items():
        lines.append(f"  {n_lines} checksummed G1 lines, {window} awaiting ok at most: {n_lines / wall_s:6,.0f} "
                     f"lines/s, {oks} ok, {resends} resends")
    outcome = f"Kp {gains[0]} Ki {gains[1]} Kd {gains[2]}" if gains else m303[-2].decode().strip()
    lines.append(f"  M303 E0 S210 C8 (default hotend): {m303_s:.3f} s wall, {len(m303)} lines, {outcome}")
    return lines


# -- twin-tune: the command as a user runs it -------------------------------------------------------
TWIN_TUNE_CLI = [sys.executable, "-m", "tools.cli.tune"]
PRESET_TUNE = ["--plant", TUNE_PRESET, "--target", f"{TUNE_TARGET_C}"]
SIM_CLI = [sys.executable, "-m", "tools.cli.sim", "--no-plot"]  # the default job: the unit of the targets
PRESET_TARGET, LOG_TARGET = 4.0, 10.0  # wall time of the default tune and of a log's, at most this many sim runs
MPC_TUNE = [*PRESET_TUNE, "--controller", "mpc"]  # the robust MPC tune of the same preset (ensemble, noise, proof)
MPC_RATIO_TARGET = 3.0  # its wall time, at most this many times the default (PID) tune's
CHEAP = ["--budget", "90", "--proof", "1"]
WARM_UPS = ([*PRESET_TUNE, "--loop", "both", *CHEAP], [*MPC_TUNE, *CHEAP])  # every kernel the cases run, cheaply
TWIN_TUNE_TIMEOUT_S = 3600  # one case, however slow: a hung one must not hang the benchmark


def _heaters(path: Path) -> list[str | None]:
    """The heaters to tune in a capture: each one a klippy.log's Stats lines report; for an M303 capture
    the one it tunes (None: twin-tune finds it, as for a user)."""
    log = load_log(path)
    if isinstance(log, StatsLog):
        return [name for name in HEATER_NAMES if any(name in session for session in log.sessions)]
    return [None]


def twin_tune_cases(patterns: tuple[str, ...]) -> list[tuple[list[str], float]]:
    """twin-tune's arguments and wall target (in default twin-sim runs) for each case: the default tune,
    then every capture matching one of ``patterns`` on each of its heaters."""
    folder = hardware_logs_dir()
    paths = sorted({path for pattern in patterns for path in folder.glob(pattern)})
    cases = [(PRESET_TUNE, PRESET_TARGET)]
    for path in paths:
        cases += [(["--from-log", str(path), *(["--heater", heater] if heater else [])], LOG_TARGET)
                  for heater in _heaters(path)]
    return cases


def _verdict(answer: Path, stderr: str) -> str:
    """What twin-tune answered (its --json: the verdict, the new gains, why), else its last line on stderr."""
    if not answer.exists():
        return stderr.strip().splitlines()[-1] if stderr.strip() else "no answer and nothing on stderr"
    document = json.loads(answer.read_text())
    gains = document["answer"]
    said = f" Kp {gains['kp']:.4g} Ki {gains['ki']:.4g} Kd {gains['kd']:.4g}" if gains else ""
    return f"{document['verdict']}{said}: {document['why']}"


def _run_process(argv: list[str], env: dict[str, str] | None = None
                 ) -> tuple[float, float, subprocess.CompletedProcess | None]:
    """One command in its own process: wall s, CPU s (the process and its threads), its outcome (None: it
    was stopped after TWIN_TUNE_TIMEOUT_S)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        done, wall_s, _ = _timed_value(lambda: subprocess.run(argv, env=env, capture_output=True, text=True,
                                                               timeout=TWIN_TUNE_TIMEOUT_S))
    except subprocess.TimeoutExpired:
        return TWIN_TUNE_TIMEOUT_S, float("nan"), None
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall_s, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, done


def _run_twin_tune(args: list[str]) -> tuple[float, float, int, str]:
    """One twin-tune in its own process: wall s, CPU s (the process and its threads), exit status, verdict."""
    with tempfile.TemporaryDirectory(prefix="bench-twin-tune") as folder:
        answer = Path(folder) / "answer.json"
        wall_s, cpu_s, done = _run_process([*TWIN_TUNE_CLI, *args, "--plot", "none", "--json", str(answer)])
        if done is None:
            return wall_s, cpu_s, -1, f"stopped after {TWIN_TUNE_TIMEOUT_S} s"
        return wall_s, cpu_s, done.returncode, _verdict(answer, done.stderr)


def _run_sim() -> tuple[float, float]:
    """The default job, ``twin-sim --no-plot``, in its own process: wall s, CPU s."""
    with tempfile.TemporaryDirectory(prefix="bench-twin-sim") as folder:
        wall_s, cpu_s, done = _run_process([*SIM_CLI, "--out", folder])
        if done is None or done.returncode != 0:
            raise RuntimeError(f"twin-sim --no-plot failed: {done.stderr if done else 'stopped'}")
        return wall_s, cpu_s


def bench_twin_tune(patterns: tuple[str, ...], sizes: list[str]) -> list[str]:
    """twin-tune's default tune and --from-log on every capture, each as a user runs it, in units of one
    default twin-sim run (timed first, the median of three, in the same run)."""
    cases = twin_tune_cases(patterns)
    for warm_up in WARM_UPS:
        _run_twin_tune(warm_up)
    _run_sim()
    sims = sorted(_run_sim() for _ in range(3))
    sim_s, sim_cpu_s = sims[1]
    lines = [f"one default job ({' '.join(['python', *SIM_CLI[1:]])}), the unit below: {sim_s:.2f} s wall, "
             f"{sim_cpu_s:.2f} s CPU (the median of 3)",
             f"twin-tune in its own process ({' '.join(['python', *TWIN_TUNE_CLI[1:]])} ARGS"
             f"{''.join(' ' + s for s in sizes)} --plot none --json FILE), after untimed warm-ups; wall time in "
             "default jobs (target), wall and CPU time (the process and its threads), exit status, verdict:"]
    for k, (args, target) in enumerate(cases):
        wall_s, cpu_s, status, verdict = _run_twin_tune(args + sizes)
        shown = " ".join(Path(a).name if i and args[i - 1] == "--from-log" else a for i, a in enumerate(args))
        lines.append(f"  twin-tune {shown}: {wall_s / sim_s:.1f} x (target <= {target:g} x), {wall_s:.1f} s wall, "
                     f"{cpu_s:.1f} s CPU, exit {status}: {verdict}")
        if k == 0:  # the default tune's MPC twin, timed against it
            mpc_s, mpc_cpu_s, mpc_status, mpc_verdict = _run_twin_tune(MPC_TUNE + sizes)
            lines.append(f"  twin-tune {' '.join(MPC_TUNE)}: {mpc_s / wall_s:.2f} x the PID tune's (target <= "
                         f"{MPC_RATIO_TARGET:g} x), {mpc_s:.1f} s wall, {mpc_cpu_s:.1f} s CPU, exit {mpc_status}: "
                         f"{mpc_verdict}")
    return lines


# -- scaling: how cost grows with lanes, horizon and dask workers ---------------------------------
SCALING_LANES = (1, 10, 100, 1000)
SCALING_HORIZONS_S = (150.0, 300.0, 600.0)
SCALING_DASK_LANES = 2048  # 64 chunks of evaluate.CHUNK_LANES: enough tasks for two workers
SCALING_REPEATS = 3  # each figure is the best of 3 runs: a loaded machine inflates single runs


def _best_wall(fn) -> float:
    return min(_timed(fn) for _ in range(SCALING_REPEATS))


def _pid_lanes(gains: np.ndarray) -> list[PidGains]:
    return [PidGains(*map(float, g)) for g in gains]


def _fuzzy_lanes(gains: np.ndarray) -> list:
    """Fuzzy PI candidates, one per row of gains: each of its three ranges log-uniform within its bounds, at
    the row's place in TUNE_BOUNDS (so the same rows give the same candidates)."""
    space = param_space("fuzzy_pi")
    low, high = space.to_search(space.bounds[:, 0]), space.to_search(space.bounds[:, 1])
    bounds = np.array(TUNE_BOUNDS)
    share = (gains - bounds[:, 0]) / (bounds[:, 1] - bounds[:, 0])
    return [space.make(row) for row in space.from_search(low + share * (high - low))]


def _klipper_batch(plant, gains: np.ndarray, score) -> KlipperBatch:
    return KlipperBatch(gains_setups(extruder_setup(plant, max_temp_c=KLIPPER_MAX_TEMP_C), gains), record=False,
                        score=score)


# name -> (plant preset and parameters, options): each path of the batch as a tuner runs it
SCALING_PATHS: dict[str, tuple[str, dict, dict]] = {
    "Marlin PID, linear plant (hotend_cartridge)": (TUNE_PRESET, {}, {}),
    "Marlin PID, 1 LSB of ADC noise": (TUNE_PRESET, {}, {"noise_lsb": 1.0, "seed": 1}),
    "Marlin PID, dead time (seed001_fopdt)": ("seed001_fopdt", {}, {}),
    "Marlin PID, radiating loss (hotend_cartridge's radiating fit)": (TUNE_PRESET, ONION_RADIATING_PARAMS, {}),
    "Marlin fuzzy PI (seed 004)": (TUNE_PRESET, {}, {"fuzzy": True}),
    "Klipper PID": (TUNE_PRESET, {}, {"klipper": True}),
}


def _path_run(path: str, gains: np.ndarray, horizon_s: float):
    """One batch of a path's lanes heating to the tuning target for horizon_s, as a tuner runs it."""
    preset, params, options = SCALING_PATHS[path]
    options = dict(options)
    plant = make_plant(preset, **params)
    score = score_spec(TUNE_TARGET_C, plant.ambient_c, horizon_s / 2, 1)
    if options.pop("klipper", False):
        klipper = _klipper_batch(plant, gains, score)
        klipper.set_target(float(TUNE_TARGET_C))
        batch: BatchTwin | KlipperBatch = klipper
    else:
        lanes = _fuzzy_lanes(gains) if options.pop("fuzzy", False) else _pid_lanes(gains)
        batch = BatchTwin(plant, lanes, record=False, score=score, **options)
        batch.set_target(TUNE_TARGET_C)
    batch.run_until(horizon_s)
    return batch


def _scaling_path(path: str, seed: int) -> list[str]:
    """Cost per evaluation of one path against the lanes (600 s) and the horizon (1000 lanes)."""
    gains = _random_gains(np.random.default_rng(seed), TUNE_BOUNDS, max(SCALING_LANES))
    _path_run(path, gains[:8], 600.0)  # kernels loaded, tables (and a radiating plant's bins) built
    per_lane = {n: _best_wall(lambda n=n: _path_run(path, gains[:n], 600.0)) / n * 1e3 for n in SCALING_LANES}
    per_horizon = {h: _best_wall(lambda h=h: _path_run(path, gains, h)) / len(gains) * 1e3
                   for h in SCALING_HORIZONS_S}
    memory = {h: _path_run(path, gains[:8], h).bytes_per_lane() / 1024 for h in (SCALING_HORIZONS_S[0], 600.0)}
    return [
        f"{path}:",
        "  ms per 600-s evaluation by lanes: " + ", ".join(f"{n} {ms:.3f}" for n, ms in per_lane.items()),
        f"  ms per evaluation of {len(gains)} lanes by horizon: "
        + ", ".join(f"{h:g} s {ms:.3f}" for h, ms in per_horizon.items())
        + f" ({per_horizon[600.0] / per_horizon[SCALING_HORIZONS_S[0]]:.2f} x from {SCALING_HORIZONS_S[0]:g} to 600 s)",
        f"  memory per lane: {memory[SCALING_HORIZONS_S[0]]:.2f} KiB at {SCALING_HORIZONS_S[0]:g} s, "
        f"{memory[600.0]:.2f} KiB at 600 s",
    ]


def _scaling_dask(seed: int) -> list[str]:
    """evaluate.simulate in-process (lanes on every CPU) against a dask LocalCluster of 1 and of 2 worker
    processes (one lane thread each), as a tuner runs it (no trace)."""
    from distributed import Client, LocalCluster

    from tools.tuning.evaluate import preset_problem, simulate

    problem = preset_problem(TUNE_PRESET, TUNE_TARGET_C)
    gains = _random_gains(np.random.default_rng(seed), TUNE_BOUNDS, SCALING_DASK_LANES)
    simulate(problem, gains[:2], record=False)  # compiled kernel loaded in this process
    walls = {"in-process": _best_wall(lambda: simulate(problem, gains, record=False))}
    saved = os.environ.get(THREADS_ENV)
    os.environ[THREADS_ENV] = "1"  # the worker processes: one lane thread each, the cluster spreads the chunks
    try:
        for workers in (1, 2):
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as \
                    cluster, Client(cluster) as client:
                simulate(problem, gains[: 2 * workers], client, record=False)  # workers import and load the kernel
                walls[f"{workers} worker(s)"] = _best_wall(
                    lambda client=client: simulate(problem, gains, client, record=False))
    finally:
        if saved is None:
            os.environ.pop(THREADS_ENV)
        else:
            os.environ[THREADS_ENV] = saved
    base = walls["in-process"]
    lines = [f"dask ({SCALING_DASK_LANES} lanes of {problem.name}, {problem.scenario.duration_s:g} s scenario, "
             f"chunks of {CHUNK_LANES}, no trace; in-process on {lane_threads(None)} lane threads, LocalCluster worker "
             "processes of 1 thread): wall, ratio to in-process"]
    lines += [f"  {name}: {wall:.3f} s, x{wall / base:.2f}" for name, wall in walls.items()]
    return lines


def bench_scaling(seed: int) -> list[str]:
    """docs/scaling.md's figures: every path against lanes and horizon, then dask workers, measured in one run."""
    lines = []
    for path in SCALING_PATHS:
        lines += _scaling_path(path, seed)
    return lines + _scaling_dask(seed)


# -- startup: each command's --help, and twin-serial until it prints its link ----------------------------
STARTUP_COMMANDS = {"twin-sim": "tools.cli.sim", "twin-serial": "tools.cli.serial",
                    "twin-klipper-mcu": "tools.cli.klipper_mcu", "twin-fit": "tools.cli.fit",
                    "twin-compare": "tools.cli.compare", "twin-tune": "tools.cli.tune",
                    "twin-firmware-report": "tools.cli.firmware_report", "tools.bench": "tools.bench",
                    "tools.seeds": "tools.seeds"}
STARTUP_HELP_CPU_S = 0.5  # the start-up targets: --help, and twin-serial's link
STARTUP_LINK_CPU_S = 1.0


def _children_cpu_s(run: Callable[[], object]) -> float:
    """CPU seconds (user + system) of the child processes ``run`` starts and waits for."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    run()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def _serial_link() -> None:
    """twin-serial until it prints its link (the pty path), then stopped."""
    with subprocess.Popen(SERIAL_CLI, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True) as proc:
        out = cast("IO[str]", proc.stdout)
        try:
            if not select.select([out], [], [], START_TIMEOUT_S)[0] or not out.readline().strip():
                raise RuntimeError("twin-serial printed no link")
        finally:
            proc.terminate()


def bench_startup(runs: int) -> list[str]:
    """The median CPU time of each command's --help, and of twin-serial until it prints its link."""
    lines = [f"start-up CPU time (user + system of the process), median of {runs} runs; targets: --help "
             f"{STARTUP_HELP_CPU_S:g} s, twin-serial's link {STARTUP_LINK_CPU_S:g} s:"]
    for name, module in STARTUP_COMMANDS.items():
        argv = [sys.executable, "-m", module, "--help"]
        help_run = functools.partial(subprocess.run, argv, capture_output=True, check=True)
        cpu_s = statistics.median(_children_cpu_s(help_run) for _ in range(runs))
        lines.append(f"  {name} --help: {cpu_s:.2f} s")
    cpu_s = statistics.median(_children_cpu_s(_serial_link) for _ in range(runs))
    return lines + [f"  twin-serial until its link: {cpu_s:.2f} s (and its stop)"]
# -- fallback: the batch without numba, against the compiled loop --------------------------------------
FALLBACK_ENV = {"NUMBA_DISABLE_JIT": "1", batch_kernel.KERNEL_ENV: "numpy"}  # what a platform without numba runs
FALLBACK_LOOP_PRESET, FALLBACK_LOOP_LANES = "seed003_third", 16  # dead time: numpy lanes, or the loop as Python


def fallback_batch_cpu_s(preset: str, n_lanes: int, duration_s: float, seed: int, kernel: str | None = None) -> float:
    """CPU seconds of one streamed heat-and-hold batch of random gains on ``kernel`` (default: the default)."""
    rng = np.random.default_rng(seed)
    gains = [PidGains(*map(float, g)) for g in _random_gains(rng, TUNE_BOUNDS, n_lanes)]
    return _timed_value(lambda: _heat_and_hold(make_plant(preset), gains, duration_s, kernel, streamed=True))[2]


def _fallback_process(argv: list[str], fallback: bool) -> tuple[subprocess.CompletedProcess, float, float]:
    """argv in its own process (compiled, or the fallback's environment): the run, wall s, CPU s."""
    env = {**os.environ, **(FALLBACK_ENV if fallback else {}), "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    wall_s, cpu_s, done = _run_process(argv, env)
    if done is None:
        raise RuntimeError(f"{' '.join(argv)}: stopped after {TWIN_TUNE_TIMEOUT_S} s")
    return done, wall_s, cpu_s


def bench_fallback(n_lanes: int, duration_s: float, seed: int, sizes: list[str]) -> list[str]:
    """The fallback's cost as a ratio to the compiled loop, measured in this run: the numpy lanes (linear
    plant), the loop as plain Python (dead time), and twin-tune's default tune in its own process."""
    fallback_batch_cpu_s(TUNE_PRESET, n_lanes, duration_s, seed, "numba")  # warm-up: numba's cache, the tables
    compiled_cpu = fallback_batch_cpu_s(TUNE_PRESET, n_lanes, duration_s, seed, "numba")
    numpy_cpu = fallback_batch_cpu_s(TUNE_PRESET, n_lanes, duration_s, seed, "numpy")
    loop_args = (FALLBACK_LOOP_PRESET, FALLBACK_LOOP_LANES, duration_s, seed)
    fallback_batch_cpu_s(*loop_args, "numba")
    loop_cpu = fallback_batch_cpu_s(*loop_args, "numba")
    probe = f"from tools.benchmarks import fallback_batch_cpu_s as f; print(f(*{loop_args!r}, 'numpy'), " \
            f"f(*{loop_args!r}, 'numba'))"  # numba's kernel without its JIT: the loop as plain Python
    plain = _fallback_process([sys.executable, "-c", probe], fallback=True)[0]
    ring_cpu, plain_cpu = map(float, plain.stdout.split()[-2:]) if plain.returncode == 0 else (float("nan"), float("nan"))
    tune_argv = [*TWIN_TUNE_CLI, *PRESET_TUNE, *sizes, "--plot", "none"]
    _fallback_process(tune_argv, fallback=False)  # warm-up: numba's cache
    tunes = {fallback: _fallback_process(tune_argv, fallback) for fallback in (False, True)}
    answers = [re.sub(r"^\(\d+(\.\d+)? s\)$", "", done.stdout, flags=re.MULTILINE) for done, _, _ in tunes.values()]
    (_, wall_s, cpu_s), (fb, fb_wall_s, fb_cpu_s) = tunes[False], tunes[True]
    same = "the same report" if answers[0] == answers[1] and fb.returncode == 0 else "REPORTS DIFFER"
    return [
        f"the batch without numba ({' '.join(f'{k}={v}' for k, v in FALLBACK_ENV.items())}: numba's decorators return "
        f"the Python functions) against the compiled loop (numba {'compiled' if batch_kernel.compiled() else 'MISSING'}), "
        f"CPU seconds, each a streamed heat-and-hold of random gains (seed {seed}) x {duration_s:g} s:",
        f"  numpy lanes, {n_lanes} lanes of {TUNE_PRESET} (linear): {numpy_cpu:.2f} s against {compiled_cpu:.2f} s "
        f"compiled: {numpy_cpu / compiled_cpu:.1f} x",
        f"  {FALLBACK_LOOP_LANES} lanes of {FALLBACK_LOOP_PRESET} (dead time) against {loop_cpu:.3f} s compiled: numpy lanes "
        f"{ring_cpu:.2f} s ({ring_cpu / loop_cpu:.0f} x); the loop as plain Python (what a radiating plant or Marlin's "
        f"MPC runs) {plain_cpu:.2f} s ({plain_cpu / loop_cpu:.0f} x, {plain_cpu / FALLBACK_LOOP_LANES:.2f} s per lane)",
        f"  twin-tune {' '.join([*PRESET_TUNE, *sizes])} in its own process: {fb_wall_s:.1f} s wall, {fb_cpu_s:.1f} s CPU "
        f"without numba against {wall_s:.1f} s wall, {cpu_s:.1f} s CPU compiled (after a warm-up): "
        f"{fb_cpu_s / cpu_s:.1f} x the CPU, {same}",
    ]


