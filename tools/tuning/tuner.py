"""Tune any controller on the twin: rules, references and an optimiser's search, scored together.

The canonical call, with a controller family of your own (firmware_port/params.py)::

    from tools.tuning.tuner import Param, ParamSpace, preset_problem, tune
    space = ParamSpace("my_pi", (Param("kp", "counts/C", 1, 100, 20), Param("ki", "counts/(C s)", 0.01, 10, 1, log=True)),
                       factory=lambda kp, ki: MyPi(kp, ki))
    result = tune(preset_problem("hotend_cartridge", 210, controller=space), method="de", budget=300, seed=1)
    result.best.params, result.best.cost, result.beats(result.references[0])

Every candidate runs the problem's scenario in its loop (tools/tuning/evaluate.py) and is scored by
the objective (tools/tuning/objectives.py). The references are the controller's own defaults (the
build's hand-set values) and, for a PID family, the firmware's own autotune on the same twin
(M303 C8, or PID_CALIBRATE on the Klipper loop). A PID family also gets the tuning rules as
candidates, and its search box is 0 .. ``SEARCH_FACTOR`` x the best rule's gains; a family with its own autotune (MPC's
M306 T) searches around that result (/ and x ``SEARCH_FACTOR``); other families
search their declared bounds (on a log scale where a parameter says so).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any
from dataclasses import dataclass, field, replace

import numpy as np

from firmware_port.params import Param, ParamSpace
from tools.tuning.evaluate import (
    Candidate,
    Evaluator,
    Problem,
    firmware_autotune,
    optimiser_names,
    preset_problem,
    rule_gains,
    rule_names,
    runs,
    score,
    simulate,
)
from tools.tuning.ensemble import Ensemble
from tools.tuning.objectives import DEFAULT_OBJECTIVE, Run, objective
from tools.tuning.optim import METHODS, WARM_STARTS
from tools.tuning.proof import PROOF_SEEDS, ProofRow, prove

__all__ = ["Candidate", "Param", "ParamSpace", "Problem", "TuneResult", "preset_problem", "simulate", "tune"]

DEFAULT_OPTIMISER = "de"
DEFAULT_BUDGET = 900  # optimiser evaluations: 20 generations of DE's default population of 45
SEARCH_FACTOR = 4.0  # the box: a PID family's 0 .. 4 x the autotune's gains (the best rule's without one); others / 4 .. x 4
MIN_BOUND = np.array([1.0, 0.05, 1.0])  # so a rule's zero Ki or Kd still leaves room to search
DEFAULTS = "defaults"  # the reference candidate of the controller's own default parameters
PROOF_TRIES = 3  # candidates proven, best first, before the tune gives up on an answer


@dataclass(frozen=True)
class TuneResult:
    """Candidates best first, the references (defaults, the firmware's autotune), and notes on what failed."""

    problem: Problem
    objective: str
    candidates: list[Candidate]
    references: list[Candidate]
    notes: list[str] = field(default_factory=list)

    @property
    def ranked(self) -> list[Candidate]:
        """Every candidate and reference, best first: a reference that no search beat stays the best."""
        return sorted(self.candidates + self.references, key=lambda c: c.cost)

    @property
    def best(self) -> Candidate:
        return self.ranked[0]

    def beats(self, reference: Candidate) -> bool:
        return self.best.cost < reference.cost

    @property
    def autotune(self) -> Candidate | None:
        """The firmware's own autotune among the references, if it ran."""
        return next((r for r in self.references if r.method != DEFAULTS), None)


@dataclass(frozen=True)
class Proven:
    """The answer a proof allows (None: every candidate tried tripped) and the proof's rows."""

    answer: Candidate | None
    rows: list[ProofRow]


def proven(result: TuneResult, seeds: int = PROOF_SEEDS, tries: int = PROOF_TRIES,
           workers: int | None = None) -> Proven:
    """Prove the best candidates in turn (tools/tuning/proof.py) until one passes, beside the firmware's
    autotune; a candidate that trips in any run is never the answer."""
    problem = result.problem
    best, autotune = result.best, result.autotune
    extra = [autotune] if autotune is not None and autotune is not best else []
    first = prove(problem, [best] + extra, seeds, workers)
    rows, answer = first[:1], best if first[0].passed else None
    for candidate in result.ranked[1:tries]:
        if answer is not None:
            break
        row = prove(problem, [candidate], seeds, workers)[0]
        rows.append(row)
        answer = candidate if row.passed else None
    return Proven(answer, rows + first[1:])


def plan(method: str, pid: bool) -> tuple[list[str], list[str]]:
    """(rules, optimisers) that ``method`` asks for; rules apply to PID families only."""
    rules, optimisers = (rule_names() if pid else []), optimiser_names()
    if method == "all":
        return rules, optimisers
    if method == "auto":
        return rules, [DEFAULT_OPTIMISER]
    if method == "rules":
        return rules, []
    if method in optimisers:
        return [], [method]
    if method in rule_names():
        if not pid:
            raise ValueError(f"--method {method}: tuning rules give PID gains; choose an optimiser, 'auto' or 'all'")
        return [method], []
    raise ValueError(f"--method {method!r}: choose one of: {', '.join(methods())}")


def methods() -> list[str]:
    """Every value ``--method`` takes."""
    return rule_names() + optimiser_names() + ["all", "auto", "rules"]


def search_bounds(problem: Problem, start: np.ndarray | None) -> np.ndarray:
    """(d, 2) box an optimiser searches: a PID family's 0 .. SEARCH_FACTOR x start; another family with a
    start (its firmware autotune's result) start / SEARCH_FACTOR .. start x SEARCH_FACTOR; else the
    declared bounds; always within the declared bounds."""
    declared = problem.controller.bounds
    if start is None:
        return declared
    start = np.asarray(start, float)
    if problem.controller.pid:
        top = np.minimum(np.maximum(SEARCH_FACTOR * start, MIN_BOUND), declared[:, 1])
        return np.column_stack([declared[:, 0], top])
    low = np.clip(start / SEARCH_FACTOR, declared[:, 0], declared[:, 1])
    high = np.clip(start * SEARCH_FACTOR, declared[:, 0], declared[:, 1])
    ok = low < high
    return np.column_stack([np.where(ok, low, declared[:, 0]), np.where(ok, high, declared[:, 1])])


def optimise(problem: Problem, cost: Callable[[Run], np.ndarray], method: str, bounds: np.ndarray, budget: int,
             seed: int, client=None, progress: bool = False, starts: np.ndarray | None = None) -> Candidate:
    """Search ``bounds`` (d, 2) with an optimiser of tools/tuning/optim, in the controller's search coordinates;
    ``starts`` (parameter rows: the rules' and the autotune's answers) seed the optimisers that take them."""
    space = problem.controller
    warm: dict[str, Any] = {} if starts is None or method not in WARM_STARTS else \
        {"starts": space.to_search(np.clip(starts, bounds[:, 0], bounds[:, 1]))}
    with _bar(budget, method, progress) as bar:
        evaluator = Evaluator(problem, cost, client, on_batch=bar)

        def objective_z(z: np.ndarray) -> np.ndarray:
            return evaluator(space.from_search(z))

        box = np.column_stack([space.to_search(bounds[:, 0]), space.to_search(bounds[:, 1])])
        try:
            result = METHODS[method](objective_z, box, rng=np.random.default_rng(seed), budget=budget, **warm)
        except ValueError as exc:  # e.g. a budget below two of the optimiser's generations
            raise ValueError(f"--method {method} --budget {budget}: {exc}") from None
    best = space.hold(np.clip(space.from_search(result.x), bounds[:, 0], bounds[:, 1]))
    return runs(problem, cost, best[None, :], [method], client, [np.asarray(result.history, float)])[0]


def references(problem: Problem, cost: Callable[[Run], np.ndarray], client=None) -> tuple[list[Candidate], list[str]]:
    """The controller's defaults and, for a PID family, the firmware's autotune on the same twin, scored;
    and why any reference could not be had."""
    table: dict[str, np.ndarray] = {}
    notes = []
    if problem.controller.autotune:
        try:
            name, params = firmware_autotune(replace(problem, loop="klipper" if problem.loop == "klipper" else "marlin"))
            table[name] = params
        except ValueError as exc:
            notes.append(str(exc))
    table[DEFAULTS] = problem.controller.defaults
    scored = {c.method: c for c in score(problem, cost, table, client)}
    return [scored[name] for name in table], notes


def hopeless_members(problem: Problem, scored: list[Candidate]) -> list[int]:
    """The ensemble's corner members (never the nominal plant) on which every scored candidate trips."""
    if problem.ensemble is None or problem.ensemble.size < 2 or not scored:
        return []
    trips = np.array([np.asarray(c.run.tripped, bool) for c in scored])  # (candidates, members)
    return [k for k in range(1, problem.ensemble.size) if trips[:, k].all()]


def without_members(ensemble: Ensemble | None, drop: list[int]) -> Ensemble | None:
    if ensemble is None:
        return None
    return replace(ensemble, members=tuple(m for k, m in enumerate(ensemble.members) if k not in drop))


def tune(problem: Problem, objective_name: str = DEFAULT_OBJECTIVE, method: str = "auto",
         budget: int = DEFAULT_BUDGET, seed: int = 0, client=None, progress: bool = False) -> TuneResult:
    """Every planned candidate scored, best first, beside the references (see the module docstring)."""
    cost = objective(objective_name)
    rules, optimisers = plan(method, problem.controller.pid)
    refs, notes = references(problem, cost, client)
    gains, failures = rule_gains(problem, rules)
    notes += [f"rule {rule} gives no gains here: {why}" for rule, why in failures.items()]
    candidates = score(problem, cost, dict(gains), client) if gains else []
    if hopeless := hopeless_members(problem, [*refs, *candidates]):
        labels = ", ".join(problem.ensemble.members[k].label for k in hopeless) if problem.ensemble else ""
        problem = replace(problem, ensemble=without_members(problem.ensemble, hopeless))
        notes.append(f"left out of the ensemble: {labels}: every rule and reference trips on that plant (the corner of "
                     "what the data cannot pin down, not a printer any gains hold); the tune and its proof run without it")
        refs = score(problem, cost, {r.method: r.params for r in refs}, client)
        candidates = score(problem, cost, dict(gains), client) if gains else []
    autotune = next((r.params for r in refs if r.method != DEFAULTS), None)
    start = autotune if autotune is not None or not candidates else candidates[0].params
    known = np.array([c.params for c in (*candidates, *refs)], float)
    for name in optimisers:
        candidates.append(optimise(problem, cost, name, search_bounds(problem, start), budget, seed, client,
                                   progress, known if len(known) else None))
    return TuneResult(problem, objective_name, sorted(candidates, key=lambda c: c.cost), refs, notes)


class _bar:
    """A tqdm progress bar on stderr (hidden when stderr is not a terminal, or unless asked); called with
    each batch's costs."""

    def __init__(self, total: int, method: str, show: bool):
        from tqdm import tqdm

        self.tqdm = tqdm(total=total, unit="eval", desc=method, file=sys.stderr, disable=None if show else True,
                         leave=False)

    def __enter__(self) -> _bar:
        return self

    def __exit__(self, *exc) -> None:
        self.tqdm.close()

    def __call__(self, costs: np.ndarray) -> None:
        self.tqdm.update(len(costs))
        self.tqdm.set_postfix(best=f"{np.min(costs):.4g}")
