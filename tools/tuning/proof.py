"""The proof of a tune: the chosen controller and the firmware's own autotune re-run on the most
faithful engine, with sensor noise over many seeds and on the ensemble's extreme plants.

Each candidate runs the problem's scenario as one scalar twin per case on the tick-by-tick
reference engine (twin/engine.py: every ISR and main-loop pass as the MCU runs them; the Klipper
loop runs its own twin): the nominal plant with noise seeds 1..``seeds``, then each corner plant
of the ensemble (tools/tuning/ensemble.py) with its own seed. The table gives, over those runs,
the mean and worst heat-up overshoot, settling time (2 % band), mean |error| while holding and
mean |duty change| per reading while holding, and the trips. A candidate passes when no run
trips. Cases run in parallel worker processes (forked; serially where fork is not available).
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
import os
from dataclasses import dataclass, replace

import numpy as np

from tools.tuning.evaluate import Candidate, Problem, Traces, run_chunk
from tools.tuning.objectives import heater_terms
from tools.tuning.objectives import Run as ObjectiveRun
from twin.metrics import step_metrics

PROOF_SEEDS = 10
NOISE_LSB = 1.0  # without an ensemble: the noise the proof adds (an ensemble's members state theirs)
_TASKS: list[tuple[Problem, np.ndarray]] = []  # what forked workers run, by index


@dataclass(frozen=True)
class ProofRow:
    """One candidate's proof: statistics over its runs (mean, worst) and its trips."""

    method: str
    params: np.ndarray
    runs: int
    trips: int
    overshoot_c: tuple[float, float]
    settling_s: tuple[float, float]  # inf where a run never settles
    hold_error_c: tuple[float, float]
    chatter: tuple[float, float]

    @property
    def passed(self) -> bool:
        return self.trips == 0


def cases(problem: Problem, seeds: int = PROOF_SEEDS) -> list[Problem]:
    """The proof's runs of one candidate: the nominal plant on seeds 1..seeds, then each corner plant."""
    nominal = problem.members()[0]
    noise = nominal.noise_lsb or NOISE_LSB
    runs = [replace(nominal, noise_lsb=noise, seed=seed, engine="reference") for seed in range(1, seeds + 1)]
    corners = problem.members()[1:]
    return runs + [replace(c, noise_lsb=c.noise_lsb or noise, engine="reference") for c in corners]


def _run_task(index: int) -> Traces:
    problem, row = _TASKS[index]
    return run_chunk(problem, row[None, :])


def _run_all(tasks: list[tuple[Problem, np.ndarray]], workers: int | None) -> list[Traces]:
    global _TASKS
    _TASKS = tasks
    workers = workers or os.cpu_count() or 1
    try:
        context = multiprocessing.get_context("fork")
    except ValueError:  # no fork on this platform
        workers = 1
    if workers <= 1 or len(tasks) <= 1:
        return [_run_task(i) for i in range(len(tasks))]
    try:
        with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=context) as pool:
            return list(pool.map(_run_task, range(len(tasks))))
    except BrokenProcessPool:  # a forked worker died (a thread pool the parent had started does not fork): here
        return [_run_task(i) for i in range(len(tasks))]


def _row(problem: Problem, candidate: Candidate, traces: list[Traces]) -> ProofRow:
    rows = min(t.t_s.size for t in traces)
    run = ObjectiveRun(traces[0].t_s[:rows], np.column_stack([t.temp_c[:rows, 0] for t in traces]),
                       np.column_stack([t.duty[:rows, 0] for t in traces]), problem.scenario.target_c,
                       problem.scenario.ambient_c, problem.scenario.disturbances_s,
                       np.concatenate([t.tripped for t in traces]), None)
    terms = heater_terms(run)
    heat = run.t_s < run.heatup_end_s
    settling = np.array([np.inf if (s := step_metrics(run.t_s[heat], run.temp_c[heat, k], run.target_c,
                                                      np.clip(run.duty[heat, k], 0, 1)).settling_time_2pct_s) is None
                         else s for k in range(run.n)])

    def stats(values: np.ndarray) -> tuple[float, float]:
        return float(np.mean(values)), float(np.max(values))

    return ProofRow(candidate.method, candidate.params, run.n, int(terms.tripped.sum()), stats(terms.overshoot_c),
                    stats(settling), stats(terms.hold_error_c), stats(terms.chatter))


def prove(problem: Problem, candidates: list[Candidate], seeds: int = PROOF_SEEDS,
          workers: int | None = None) -> list[ProofRow]:
    """Each candidate over the proof's cases (see the module docstring), in order."""
    runs = cases(problem, seeds)
    tasks = [(case, c.params) for c in candidates for case in runs]
    traces = _run_all(tasks, workers)
    n = len(runs)
    return [_row(problem, c, traces[k * n:(k + 1) * n]) for k, c in enumerate(candidates)]


def table(rows: list[ProofRow], describe) -> list[str]:
    """The proof as text lines: one row per candidate, ``describe(row)`` naming its parameters."""
    head = (f"{'candidate':<12} {'trips':>7}  {'overshoot C':>13}  {'settling s':>13}  {'hold |e| C':>11}  "
            f"{'|du|/reading':>13}  (mean / worst)")
    lines = [head]
    for r in rows:
        def pair(p: tuple[float, float], digits: int = 2) -> str:
            return f"{p[0]:.{digits}f} / {p[1]:.{digits}f}"

        lines.append(f"{r.method:<12} {r.trips:>3} of {r.runs:<2} {pair(r.overshoot_c):>13}  "
                     f"{pair(r.settling_s, 1):>13}  {pair(r.hold_error_c):>11}  {pair(r.chatter, 3):>13}  "
                     f"{describe(r)}")
    return lines
