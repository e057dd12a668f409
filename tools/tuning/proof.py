"""The proof of a tune: candidates and the printer's own gains on every member of the ensemble, over many
noise seeds, on the compiled batch; the reference engine cross-checks a sample.

Each candidate runs the problem's scenario on each member of the ensemble (tools/tuning/ensemble.py)
with ADC noise on seeds 1..``seeds`` (the member's own noise, or ``NOISE_LSB`` where it has none): the
candidates and seeds of one member are lanes of one batch (tools/tuning/evaluate.py ``run_chunk``: the
firmware's lanes equal its scalar twin reading for reading, tests/twin/test_batch_paths.py; a controller
without a lane law runs one scalar twin per lane). A row per member and candidate gives, over its seeds,
the mean and worst heat-up overshoot, settling time (2 % band), mean |error| while holding, mean |duty
change| per reading while holding, the runs whose heat-up hold limit-cycles (twin/metrics.py) and the
largest amplitude, the heater objective, and the trips.

The cross-check (``cross_check``): the first candidate on the first member with seed 1 re-run for its
first ``CROSS_CHECK_S`` seconds on the tick-by-tick reference engine (every ISR and main-loop pass as
the MCU runs them; the Klipper loop: one KlipperTwin), its readings against the batch lane's: equal, or
the proof stops with the difference (a bug, not a tuning result).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from tools.tuning.evaluate import Candidate, Problem, Traces, run_chunk
from tools.tuning.objectives import HeaterTerms, heater_terms
from tools.tuning.objectives import Run as ObjectiveRun
from tools.tuning.defaults import CROSS_CHECK_S, PROOF_SEEDS
from twin.metrics import LimitCycle, limit_cycles, step_metrics

NOISE_LSB = 1.0  # a member without noise of its own is proven with this much (an M303 capture's readings scatter so)
KLIPPER_CROSS_CHECK_C = 1e-9  # the Klipper loop's lanes equal KlipperTwin to float rounding


@dataclass(frozen=True)
class ProofRow:
    """One candidate on one member: statistics over its seeds (mean, worst) and its trips."""

    member: str
    method: str
    params: np.ndarray
    runs: int
    trips: int
    overshoot_c: tuple[float, float]
    settling_s: tuple[float, float]  # inf where a run never settles
    hold_error_c: tuple[float, float]
    chatter: tuple[float, float]
    cost_s: tuple[float, float]  # the heater objective
    limit_cycles: int = 0  # runs whose heat-up hold limit-cycles (twin/metrics.py limit_cycles)
    limit_cycle_c: float = 0.0  # the largest such amplitude (+- C)

    @property
    def passed(self) -> bool:
        return self.trips == 0


def _member_noise(member: Problem) -> Problem:
    return member if member.noise_lsb else replace(member, noise_lsb=NOISE_LSB)


def member_runs(member: Problem, params: np.ndarray, seeds: int) -> tuple[ObjectiveRun, Traces]:
    """The candidates (N, d) on one member over seeds 1..seeds: lanes candidate-major, (N x seeds)."""
    member = _member_noise(member)
    table = np.repeat(np.atleast_2d(params), seeds, axis=0)
    lane_seeds = np.tile(np.arange(1, seeds + 1), len(params)).tolist()
    traces = run_chunk(member, table, record=True, seeds=lane_seeds)
    run = ObjectiveRun(traces.t_s, traces.temp_c, traces.duty, member.scenario.target_c, member.scenario.ambient_c,
                       member.scenario.disturbances_s, traces.tripped, None)
    return run, traces


def _stats(values: np.ndarray) -> tuple[float, float]:
    return float(np.mean(values)), float(np.max(values))


def _limit_cycles(run: ObjectiveRun) -> list[LimitCycle | None]:
    """Each lane's limit cycle in the heat-up's hold (before the first disturbance)."""
    heat = run.t_s < run.heatup_end_s
    return limit_cycles(run.t_s[heat], run.temp_c[heat], run.target_c)


def _settling(run: ObjectiveRun) -> np.ndarray:
    heat = run.t_s < run.heatup_end_s
    out = []
    for k in range(run.n):
        s = step_metrics(run.t_s[heat], run.temp_c[heat, k], run.target_c,
                         np.clip(run.duty[heat, k], 0, 1)).settling_time_2pct_s
        out.append(np.inf if s is None else s)
    return np.array(out)


def rows_of(label: str, candidates: list[Candidate], run: ObjectiveRun, seeds: int) -> list[ProofRow]:
    """A ProofRow per candidate from a member's run (lanes candidate-major, ``seeds`` each)."""
    terms = heater_terms(run)
    settling = _settling(run)
    cycles = _limit_cycles(run)
    rows = []
    for i, c in enumerate(candidates):
        lanes = slice(i * seeds, (i + 1) * seeds)
        part = HeaterTerms(*(getattr(terms, f.name)[lanes] for f in dataclasses.fields(terms)))
        found = [lc for lc in cycles[lanes] if lc is not None]
        rows.append(ProofRow(label, c.method, c.params, seeds, int(part.tripped.sum()), _stats(part.overshoot_c),
                             _stats(settling[lanes]), _stats(part.hold_error_c), _stats(part.chatter),
                             _stats(part.cost_s), len(found), max((lc.amplitude_c for lc in found), default=0.0)))
    return rows


def prove(problem: Problem, candidates: list[Candidate], seeds: int = PROOF_SEEDS,
          on_member: Callable[[], None] | None = None) -> list[ProofRow]:
    """Each candidate on each member over the seeds (module docstring): rows member-major, in the
    candidates' order within a member. ``on_member`` is called as each member finishes (a progress bar)."""
    params = np.array([c.params for c in candidates], float)
    labels = [m.label for m in problem.ensemble.members] if problem.ensemble else ["nominal"]
    rows = []
    for label, member in zip(labels, problem.members()):
        run, _ = member_runs(member, params, seeds)
        rows += rows_of(label, candidates, run, seeds)
        if on_member is not None:
            on_member()
    return rows


def cross_check(problem: Problem, candidate: Candidate, seconds: float = CROSS_CHECK_S) -> str:
    """The candidate on the first member, seed 1, for ``seconds``: the batch's readings against the reference
    engine's (module docstring); what was compared, or RuntimeError naming the first difference."""
    member = replace(_member_noise(problem.members()[0]), seed=1)
    short = replace(member, scenario=replace(member.scenario, duration_s=seconds,
                                             events=tuple(e for e in member.scenario.events if e.at_s < seconds)))
    row = np.atleast_2d(candidate.params)
    batch = run_chunk(short, row)
    reference = run_chunk(replace(short, engine="reference"), row)
    rows = min(len(batch.t_s), len(reference.t_s))
    got, want = batch.temp_c[:rows, 0], reference.temp_c[:rows, 0]
    tolerance = KLIPPER_CROSS_CHECK_C if problem.loop == "klipper" else 0.0
    differ = np.flatnonzero(np.abs(got - want) > tolerance)
    engine = "KlipperTwin" if problem.loop == "klipper" else "the reference engine"
    if differ.size:
        k = int(differ[0])
        raise RuntimeError(f"cross-check: at {batch.t_s[k]:.3f} s the batch read {got[k]!r} C, {engine} "
                           f"{want[k]!r} C ({candidate.method} on {problem.name}, seed 1)")
    if rows == 0 or not batch.tripped[0] == reference.tripped[0]:
        raise RuntimeError(f"cross-check: the batch and {engine} disagree on a trip ({candidate.method})")
    return (f"{candidate.method} on the nominal plant, seed 1, {seconds:g} s: {rows} readings of the batch equal "
            f"{engine}'s" + (" (to float rounding)" if tolerance else " (bit for bit)"))


def table(rows: list[ProofRow], describe: Callable[[ProofRow], str]) -> list[str]:
    """The proof as text lines: one row per member and candidate, ``describe(row)`` naming its parameters."""
    width = max([len(r.member) for r in rows] + [6])
    head = (f"{'member':<{width}} {'candidate':<12} {'trips':>8}  {'overshoot C':>13}  {'settling s':>13}  "
            f"{'hold |e| C':>11}  {'|du|/reading':>13}  {'limit cycle':>13}  (mean / worst)")
    lines = [head]
    for r in rows:
        def pair(p: tuple[float, float], digits: int = 2) -> str:
            return f"{p[0]:.{digits}f} / {p[1]:.{digits}f}"

        cycle = f"{r.limit_cycles} +-{r.limit_cycle_c:.1f} C" if r.limit_cycles else "none"
        lines.append(f"{r.member:<{width}} {r.method:<12} {r.trips:>3} of {r.runs:<3} {pair(r.overshoot_c):>13}  "
                     f"{pair(r.settling_s, 1):>13}  {pair(r.hold_error_c):>11}  {pair(r.chatter, 3):>13}  "
                     f"{cycle:>13}  {describe(r)}")
    return lines
