"""Benchmarks (not tests): ``python -m tools.bench twin``. Ratios measured in one run.

- single twin, hotend + bed, fixed-point PID, full ISR fidelity, 600 s heat-and-hold: real-time
  factor of the fast engine, of the tick-by-tick reference engine, and their ratio;
- a batch of 1000 hotend twins x 600 s with different gains: wall time and firmware control
  periods per second;
- the same linear plant open loop on a PWM input: the engine's exact tick maps vs
  scipy.signal.lsim on the same 1.024 ms grid, time ratio and largest difference.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.signal

from firmware_port.marlin.constants import SOFT_PWM_PERIOD_TICKS, TICKS_PER_READING
from firmware_port.marlin.pid import PidGains
from twin.batch import BatchTwin
from twin.build import build_twin
from twin.linear import SENSOR, TICK_S
from twin.plants import make_plant
from twin.scenario import PRESETS, with_overrides


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def bench_single(duration_s: float) -> list[str]:
    scenario = with_overrides(PRESETS["heat_hold"], duration_s=duration_s)
    walls = {}
    for engine in ("fast", "reference"):
        twin = build_twin(scenario, "pid", engine=engine)
        walls[engine] = _timed(lambda: twin.run_until(duration_s))
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
    """A PWM input at 40 % on the default hotend: engine maps vs lsim on the tick grid."""
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
        f"open loop, default hotend, 40 % PWM for {duration_s:g} s ({n_ticks} ticks):",
        f"  engine {wall_engine:.3f} s, scipy.signal.lsim {wall_lsim:.3f} s, "
        f"lsim / engine {wall_lsim / wall_engine:.1f} x, largest difference {diff:.2e} C",
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.bench", description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["twin"], help="what to benchmark")
    parser.add_argument("--duration", type=float, default=600.0, help="virtual seconds (default 600)")
    parser.add_argument("--lanes", type=int, default=1000, help="batch lanes (default 1000)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the batch's random gains (default 1)")
    args = parser.parse_args(argv)
    lines = bench_single(args.duration) + bench_batch(args.lanes, args.duration, args.seed)
    lines += bench_open_loop(args.duration)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
