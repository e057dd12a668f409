"""Benchmarks (not tests): ``python -m tools.bench twin|protocol``. Ratios measured in one run.

``twin``:
- single twin, hotend + bed, fixed-point PID, full ISR fidelity, 600 s heat-and-hold: real-time
  factor of the fast engine, of the tick-by-tick reference engine, and their ratio;
- a batch of 1000 hotend twins x 600 s with different gains: wall time and firmware control
  periods per second;
- the same linear plant open loop on a PWM input: the engine's exact tick maps vs
  scipy.signal.lsim on the same 1.024 ms grid, time ratio and largest difference.

``tune``: what a tuner pays for an evaluation, in one run:
- a batch of 1000 hotend twins (the tuning plant) x 600 s, full ISR fidelity: the cost of one
  600-s firmware-in-the-loop evaluation, against one evaluation of seed 000's idealised loop
  (its second-order plant closed with a PID by scipy.signal, step over 50 s, 1000 points), and
  their ratio; firmware control periods per second; memory per lane; the same batch on the
  numpy lanes for comparison;
- the wall time of a differential-evolution tune of the three gains (population 45, 100
  generations, every population one batch) with twin-tune's heater objective on its default
  scenario.

``protocol``: twin-serial ``--speed max`` in its own process, pyserial on its pty, as a host:
- M105 round trip, wall milliseconds, median and 99th percentile;
- numbered, checksummed G1 lines streamed with 1 and with BUFSIZE (4) lines awaiting their ok:
  lines per second, oks and resends (none expected: a clean wire loses nothing);
- the wall time of ``M303 E0 S210 C8`` on the default hotend.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import select
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from typing import TypeVar, cast

import numpy as np
import scipy.optimize
import scipy.signal
import serial

from firmware_port.marlin.constants import SOFT_PWM_PERIOD_TICKS, TICKS_PER_READING
from firmware_port.marlin.pid import PidGains
from protocol.lines import with_checksum
from protocol.printer import BUFSIZE
from tools.tuning.evaluate import Evaluator, preset_problem
from tools.tuning.objectives import DEFAULT_OBJECTIVE, objective
from twin import batch_kernel
from twin.batch import BatchTwin
from twin.build import build_twin
from twin.linear import SENSOR, TICK_S
from twin.plants import SPECS, TransferFunction, make_plant
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
    periods = n_lanes * len(batch.t_s)
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
    result = {}
    wall_lsim = _timed(lambda: result.update(out=scipy.signal.lsim(system, inputs, t, X0=x0, interp=False)[1]))
    lsim_at_chunks = result["out"][::TICKS_PER_READING]
    diff = np.max(np.abs(np.array(temps) - lsim_at_chunks[: len(temps)]))
    return [
        f"open loop, MPC hotend, 40 % PWM for {duration_s:g} s ({n_ticks} ticks):",
        f"  engine {wall_engine:.3f} s, scipy.signal.lsim {wall_lsim:.3f} s, "
        f"lsim / engine {wall_lsim / wall_engine:.1f} x, largest difference {diff:.2e} C",
    ]


TUNE_TARGET_C = 210
TUNE_PRESET = "hotend_cartridge"  # linear without dead time, fitted to a real printer (twin/plants.py)
TUNE_BOUNDS = [(1.0, 100.0), (0.01, 10.0), (1.0, 500.0)]  # Kp, Ki /s, Kd s on Marlin's 0..255 scale
SEED000_HORIZON_S, SEED000_POINTS = 50.0, 1000
# Seed 000's Nelder-Mead bounds for its PID on the 5 C/W second-order extruder.
SEED000_BOUNDS = [(0.01, 10.0), (0.001, 1.0), (0.001, 1.0)]


def _timed_value(fn: Callable[[], T]) -> tuple[T, float, float]:
    """fn's value, its wall time and this process's CPU time (what a busy machine inflates less)."""
    start, start_cpu = time.perf_counter(), time.process_time()
    value = fn()
    return value, time.perf_counter() - start, time.process_time() - start_cpu


def _heat_and_hold(plant, gains: list[PidGains], duration_s: float, kernel: str | None = None) -> BatchTwin:
    batch = BatchTwin(plant, gains, kernel=kernel)
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
    """One 600-s evaluation in the batch against one seed-000 evaluation, measured in this run."""
    rng = np.random.default_rng(seed)
    gains = [PidGains(*map(float, g)) for g in _random_gains(rng, TUNE_BOUNDS, n_lanes)]
    _heat_and_hold(plant, gains[:2], 1.0)  # loads the compiled kernel from numba's cache (or compiles it)
    batch, wall_s, cpu_s = _timed_value(lambda: _heat_and_hold(plant, gains, duration_s))
    wall_numpy_s = _timed(lambda: _heat_and_hold(plant, gains, duration_s, kernel="numpy"))
    t = np.linspace(0.0, SEED000_HORIZON_S, SEED000_POINTS)
    seed_gains = _random_gains(rng, SEED000_BOUNDS, n_seed000)
    wall_seed000_s = _timed(lambda: [_seed000_evaluation(kp, ki, kd, t) for kp, ki, kd in seed_gains])
    twin_ms, seed000_ms = wall_s / n_lanes * 1e3, wall_seed000_s / n_seed000 * 1e3
    periods = n_lanes * len(batch.t_s)
    return [
        f"evaluation cost, {n_lanes} lanes of {plant.preset} x {duration_s:g} s, full ISR fidelity, random gains "
        f"(seed {seed}), kernel {batch.kernel} ({batch_kernel.describe()}):",
        f"  seed 000 comparison: {twin_ms:.3f} ms per {duration_s:g}-s firmware-in-the-loop evaluation in the batch, "
        f"{seed000_ms:.3f} ms per seed-000 evaluation (scipy.signal.step, {SEED000_HORIZON_S:g} s, "
        f"{SEED000_POINTS} points, mean of {n_seed000}): ratio {seed000_ms / twin_ms:.1f} x (target >= 10)",
        f"  {periods / wall_s:,.0f} firmware control periods per second ({wall_s:.3f} s wall, {cpu_s:.3f} s CPU "
        f"for the batch; "
        f"numpy lanes {wall_numpy_s:.3f} s, {wall_numpy_s / wall_s:.1f} x slower)",
        f"  memory per lane: {batch.bytes_per_lane() / 1024:.1f} KiB ({len(batch.t_s)} readings recorded: "
        f"temperature and duty as int16, block and sensor as float64, plus state)",
    ]


def bench_de_tune(preset: str, seed: int, popsize: int = 15, generations: int = 100) -> list[str]:
    """scipy's differential evolution on the firmware twin with twin-tune's heater objective on its
    default scenario (heat-up, hold, disturbances), one batch per population."""
    problem = preset_problem(preset, TUNE_TARGET_C)
    evaluate = Evaluator(problem, objective(DEFAULT_OBJECTIVE))
    de, wall_s, cpu_s = _timed_value(lambda: scipy.optimize.differential_evolution(
        lambda population: evaluate(population.T), TUNE_BOUNDS, popsize=popsize, maxiter=generations, tol=0.0,
        polish=False, vectorized=True, updating="deferred", rng=np.random.default_rng(seed)))
    kp, ki, kd = de.x
    return [
        f"DE tune of {preset} (3 gains, population {popsize * len(TUNE_BOUNDS)}, {de.nit} generations, "
        f"{evaluate.evaluations} evaluations of {problem.scenario.duration_s:g} s, objective {DEFAULT_OBJECTIVE}, "
        f"seed {seed}): {wall_s:.3f} s wall (target < 5 s), {cpu_s:.3f} s CPU",
        f"  best Kp {kp:.3f} Ki {ki:.4f} Kd {kd:.2f}: cost {de.fun:.1f}",
    ]


def tune_plant():
    """The tuning preset if it is linear without dead time (what a batch needs), else the MPC "hotend"."""
    plant = make_plant(TUNE_PRESET)
    return plant if plant.linear and not plant.delay_ticks else make_plant("hotend")


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
    lines = []
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


# -- scaling: how cost grows with lanes, horizon and dask workers ---------------------------------
SCALING_LANES = (1, 10, 100, 1000)
SCALING_HORIZONS_S = (150.0, 300.0, 600.0)
SCALING_HORIZON_LANES = 1000
SCALING_DASK_LANES = 2048  # 64 chunks of evaluate.CHUNK_LANES: enough tasks for two workers
SCALING_REPEATS = 3  # each figure is the best of 3 runs: a loaded machine inflates single runs


def _best_wall(fn) -> float:
    return min(_timed(fn) for _ in range(SCALING_REPEATS))


def _scaling_lanes(plant, seed: int) -> list[str]:
    """Wall time of a 600-s batch against its lane count, relative to one lane."""
    rng = np.random.default_rng(seed)
    gains = [PidGains(*map(float, g)) for g in _random_gains(rng, TUNE_BOUNDS, max(SCALING_LANES))]
    _heat_and_hold(plant, gains[:2], 1.0)  # loads the compiled kernel first
    walls = {n: _best_wall(lambda n=n: _heat_and_hold(plant, gains[:n], 600.0)) for n in SCALING_LANES}
    lines = [f"lanes ({plant.preset}, 600 s, full ISR fidelity): wall, wall per lane, ratio of wall to 1 lane's"]
    lines += [f"  {n:5d} lanes: {w:.3f} s, {w / n * 1e3:.2f} ms per lane, x{w / walls[1]:.1f}" for n, w in walls.items()]
    return lines


def _scaling_horizon(plant, seed: int) -> list[str]:
    """Wall time and memory per lane against the simulated horizon."""
    rng = np.random.default_rng(seed)
    gains = [PidGains(*map(float, g)) for g in _random_gains(rng, TUNE_BOUNDS, SCALING_HORIZON_LANES)]
    walls = {h: _best_wall(lambda h=h: _heat_and_hold(plant, gains, h)) for h in SCALING_HORIZONS_S}
    first = walls[SCALING_HORIZONS_S[0]]
    lines = [f"horizon ({SCALING_HORIZON_LANES} lanes): wall, ratio to {SCALING_HORIZONS_S[0]:g} s, memory per lane"]
    lines += [f"  {h:5g} s: {wall:.3f} s, x{wall / first:.2f}, "
              f"{_heat_and_hold(plant, gains[:1], h).bytes_per_lane() / 1024:.1f} KiB per lane"
              for h, wall in walls.items()]
    return lines


def _scaling_dask(seed: int) -> list[str]:
    """evaluate.simulate in-process against a dask LocalCluster of 1 and of 2 worker processes."""
    from distributed import Client, LocalCluster

    from tools.tuning.evaluate import preset_problem, simulate

    problem = preset_problem(TUNE_PRESET, TUNE_TARGET_C)
    gains = _random_gains(np.random.default_rng(seed), TUNE_BOUNDS, SCALING_DASK_LANES)
    simulate(problem, gains[:2])  # compiled kernel loaded in this process
    walls = {"in-process": _best_wall(lambda: simulate(problem, gains))}
    for workers in (1, 2):
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            simulate(problem, gains[: 2 * workers], client)  # workers import and load the kernel
            walls[f"{workers} worker(s)"] = _best_wall(lambda client=client: simulate(problem, gains, client))
    base = walls["in-process"]
    lines = [f"dask ({SCALING_DASK_LANES} lanes of {problem.name}, {problem.scenario.duration_s:g} s scenario, "
             f"chunks of 32, LocalCluster worker processes of 1 thread): wall, ratio to in-process"]
    lines += [f"  {name}: {wall:.3f} s, x{wall / base:.2f}" for name, wall in walls.items()]
    return lines


def bench_scaling(seed: int) -> list[str]:
    """docs/scaling.md's figures: lanes, horizon, dask workers, measured in one run."""
    plant = tune_plant()
    return _scaling_lanes(plant, seed) + _scaling_horizon(plant, seed) + _scaling_dask(seed)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.bench", description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["twin", "tune", "protocol", "scaling"], help="what to benchmark")
    parser.add_argument("--duration", type=float, default=600.0, help="twin: virtual seconds (default 600)")
    parser.add_argument("--lanes", type=int, default=1000, help="twin, tune: batch lanes (default 1000)")
    parser.add_argument("--seed", type=int, default=1, help="twin, tune: seed of the random gains and of DE (default 1)")
    parser.add_argument("--requests", type=int, default=500, help="protocol: M105 round trips (default 500)")
    parser.add_argument("--lines", type=int, default=5000, help="protocol: G1 lines per stream (default 5000)")
    args = parser.parse_args(argv)
    if args.what == "twin":
        lines = bench_single(args.duration) + bench_batch(args.lanes, args.duration, args.seed)
        lines += bench_open_loop(args.duration)
    elif args.what == "tune":
        plant = tune_plant()
        lines = bench_evaluation_cost(plant, args.lanes, args.duration, args.seed, n_seed000=200)
        lines += bench_de_tune(plant.preset, args.seed)
    elif args.what == "scaling":
        lines = [f"python -m tools.bench scaling --seed {args.seed}"] + bench_scaling(args.seed)
    else:
        lines = [f"python -m tools.bench protocol --requests {args.requests} --lines {args.lines}"]
        lines += bench_protocol(args.requests, args.lines)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
