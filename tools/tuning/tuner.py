"""Tune any controller on the twin: rules, references and an optimiser's search, scored together.

The canonical call, with a controller family of your own (firmware_port/params.py)::

    from tools.tuning.tuner import Param, ParamSpace, preset_problem, tune
    space = ParamSpace("my_pi", (Param("kp", "counts/C", 1, 100, 20), Param("ki", "counts/(C s)", 0.01, 10, 1, log=True)),
                       factory=lambda kp, ki: MyPi(kp, ki))
    result = tune(preset_problem("hotend_cartridge", 210, controller=space), method="de", budget=300, seed=1)
    result.best.params, result.best.cost, result.beats(result.references[0])

Every candidate runs the problem's scenario in its loop (tools/tuning/evaluate.py) and is scored by
the objective (tools/tuning/objectives.py). The references are the printer's own gains where they are
known (a log's, or given), the controller's own defaults (the build's hand-set values) and, for a PID
family, the firmware's own autotune on the same twin (M303 C8, or PID_CALIBRATE on the Klipper loop).
The reference to beat (``TuneResult.yours``) is the printer's gains, else the autotune's, else the
defaults; with the heater objective the search is charged for every member on which a candidate is
worse than it beyond the verdict's bounds (tools/tuning/verdict.py), and ``proven`` gives the answer:
the best candidates and the reference proven on every member over many seeds, new gains only where
they beat it. A PID family also gets the tuning rules as
candidates, and its search box is 0 .. ``SEARCH_FACTOR`` x the best rule's gains; a family with its own autotune (MPC's
M306 T) searches around that result (/ and x ``SEARCH_FACTOR``); other families
search their declared bounds (on a log scale where a parameter says so).
"""

from __future__ import annotations

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
    preset_problem,
    rule_gains,
    runs,
    score,
    simulate,
)
from tools.tuning.defaults import DEFAULT_BUDGET, DEFAULT_OBJECTIVE, methods, optimiser_names, rule_names
from tools.tuning.ensemble import Ensemble
from tools.tuning.objectives import Against, Run, heater_cost, heater_terms, objective
from tools.tuning.optim import METHODS, WARM_STARTS
from tools.tuning.proof import CROSS_CHECK_S, PROOF_SEEDS, ProofRow, cross_check, prove
from tools.tuning.verdict import HOLD_FACTOR, HOLD_SLACK_C, OVERSHOOT_SLACK_C, Verdict, judge
from twin.limits import UserError

__all__ = ["Candidate", "Param", "ParamSpace", "Problem", "TuneResult", "preset_problem", "simulate", "tune"]

DEFAULT_OPTIMISER = "de"
SEARCH_FACTOR = 4.0  # the box: a PID family's 0 .. 4 x the autotune's gains (the best rule's without one); others / 4 .. x 4
MIN_BOUND = np.array([1.0, 0.05, 1.0])  # so a rule's zero Ki or Kd still leaves room to search
DEFAULTS = "defaults"  # the reference candidate of the controller's own default parameters
YOURS = "yours"  # the reference candidate of the printer's own gains
PROOF_TRIES = 8  # candidates proven with the reference, best first: the first that beats it is the answer
RUNNERS_UP = 5  # an optimiser's next cheapest points, proven beside its best
RUNNER_UP_APART = 0.02  # runners-up differ from each other and the best by more than 2 % in some parameter
BEYOND_S_PER_C = 1000.0  # the search's charge per degC a member's hold or overshoot is beyond the verdict's bound


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
        return next((r for r in self.references if r.method not in (DEFAULTS, YOURS)), None)

    @property
    def yours(self) -> Candidate:
        """The reference to beat: the printer's own gains, else the firmware's autotune, else the defaults."""
        return reference_to_beat(self.references)


def reference_to_beat(references: list[Candidate]) -> Candidate:
    by = {r.method: r for r in references}
    if YOURS in by:
        return by[YOURS]
    return next((r for r in references if r.method != DEFAULTS), by[DEFAULTS])


@dataclass(frozen=True)
class Proven:
    """The proof's verdict, its rows (member-major), the answer (None: keep your gains, or nothing beats
    them), the reference it beat, and what the reference engine cross-checked."""

    verdict: Verdict
    rows: list[ProofRow]
    answer: Candidate | None
    yours: Candidate
    cross_check: str


def proven(result: TuneResult, seeds: int = PROOF_SEEDS, tries: int = PROOF_TRIES, cross_check_s: float = CROSS_CHECK_S,
           on_step: Step | None = None) -> Proven:
    """The best ``tries`` candidates (by the search's cost) and the reference proven together on every
    member over ``seeds`` noise seeds (tools/tuning/proof.py); the verdict (tools/tuning/verdict.py): the
    first that beats the reference, else keep your gains. The reference engine cross-checks the first
    candidate's first ``cross_check_s`` seconds (0: not)."""
    problem, yours = result.problem, result.yours
    tried = [c for c in result.ranked if c.method not in (YOURS, DEFAULTS) and c is not yours][:tries]
    members = len(problem.members())
    rows = prove(problem, tried + [yours], seeds, None if on_step is None else on_step("proving", members))
    verdict = judge(rows, yours.method, [c.method for c in tried], problem.ensemble)
    answer = next((c for c in tried if c.method == verdict.method), None)
    checked = cross_check(problem, tried[0] if tried else yours, cross_check_s) if cross_check_s > 0 else "not run"
    return Proven(verdict, rows, answer, yours, checked)


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
            raise UserError(f"--method {method}: tuning rules give PID gains; choose an optimiser, 'auto' or 'all'")
        return [method], []
    raise UserError(f"--method {method!r}: choose one of: {', '.join(methods())}")


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


Step = Callable[[str, int], Callable[..., None]]  # (what, total) -> advance(n=1): a progress report


def optimise(problem: Problem, cost: Callable[[Run], np.ndarray], method: str, bounds: np.ndarray, budget: int,
             seed: int, client=None, progress: bool = False, starts: np.ndarray | None = None) -> Candidate:
    """The best point of ``search`` (no runners-up)."""
    return search(problem, cost, method, bounds, budget, seed, client, _steps(progress), starts)[0]


def search(problem: Problem, cost: Callable[[Run], np.ndarray], method: str, bounds: np.ndarray, budget: int,
           seed: int, client=None, on_step: Step | None = None, starts: np.ndarray | None = None,
           runners_up: int = 0) -> list[Candidate]:
    """Search ``bounds`` (d, 2) with an optimiser of tools/tuning/optim, in the controller's search coordinates;
    ``starts`` (parameter rows: the rules' and the autotune's answers) seed the optimisers that take them.
    The best point, then up to ``runners_up`` of the cheapest other points it evaluated (apart from each
    other by RUNNER_UP_APART), scored: what a proof falls back on where the best trips on a seed the
    search did not draw."""
    space = problem.controller
    warm: dict[str, Any] = {} if starts is None or method not in WARM_STARTS else \
        {"starts": space.to_search(np.clip(starts, bounds[:, 0], bounds[:, 1]))}
    advance = on_step(f"searching ({method})", budget) if on_step is not None else None
    evaluator = Evaluator(problem, cost, client, on_batch=None if advance is None else lambda c: advance(len(c)))

    def objective_z(z: np.ndarray) -> np.ndarray:
        return evaluator(space.from_search(z))

    box = np.column_stack([space.to_search(bounds[:, 0]), space.to_search(bounds[:, 1])])
    try:
        result = METHODS[method](objective_z, box, rng=np.random.default_rng(seed), budget=budget, **warm)
    except ValueError as exc:  # e.g. a budget below two of the optimiser's generations
        raise UserError(f"--method {method} --budget {budget}: {exc}") from None
    best = space.hold(np.clip(space.from_search(result.x), bounds[:, 0], bounds[:, 1]))
    others = [space.hold(row) for row in evaluator.best(runners_up + 1, RUNNER_UP_APART)
              if np.any(np.abs(space.hold(row) - best) > RUNNER_UP_APART * np.maximum(np.abs(best), 1e-12))]
    table = np.array([best, *others[:runners_up]])
    names = [method] + [f"{method} #{k}" for k in range(2, len(table) + 1)]
    histories = [np.asarray(result.history, float)] + [None] * (len(table) - 1)
    return runs(problem, cost, table, names, client, histories)


def references(problem: Problem, cost: Callable[[Run], np.ndarray], client=None, yours: np.ndarray | None = None
               ) -> tuple[list[Candidate], list[str]]:
    """The printer's own gains (``yours``, where known), the controller's defaults and, for a PID family, the
    firmware's autotune on the same twin, scored; and why any reference could not be had."""
    table: dict[str, np.ndarray] = {} if yours is None else {YOURS: np.asarray(yours, float)}
    notes = []
    if problem.controller.autotune:
        try:
            name, params = firmware_autotune(problem)
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
    ensemble = problem.ensemble
    trips = np.array([np.asarray(c.run.tripped, bool).reshape(ensemble.size, ensemble.seeds).any(axis=1)
                      for c in scored])  # (candidates, members): a trip on any of a member's seeds
    return [k for k in range(1, ensemble.size) if trips[:, k].all()]


def without_members(ensemble: Ensemble | None, drop: list[int]) -> Ensemble | None:
    if ensemble is None:
        return None
    return replace(ensemble, members=tuple(m for k, m in enumerate(ensemble.members) if k not in drop))


def rescored(problem: Problem, cost: Callable[[Run], np.ndarray], candidates: list[Candidate]) -> list[Candidate]:
    """The candidates under another cost of the same runs (one lane per member each), best first."""
    out = []
    for c in candidates:
        member_costs = cost(c.run)
        out.append(replace(c, cost=float(problem.reduce(member_costs[:, None])[0]), member_costs=member_costs))
    return sorted(out, key=lambda c: c.cost)


def against(problem: Problem, yours: Candidate) -> Against:
    """The heater objective charged where a candidate is worse than ``yours`` on a member beyond the
    verdict's bounds (tools/tuning/verdict.py), on the search's one seed per member."""
    terms = heater_terms(yours.run)
    hold = np.where(terms.tripped, np.inf, terms.hold_error_c * HOLD_FACTOR + HOLD_SLACK_C)
    overshoot = np.where(terms.tripped, np.inf, terms.overshoot_c + OVERSHOOT_SLACK_C)
    return Against(hold, overshoot, BEYOND_S_PER_C)


def tune(problem: Problem, objective_name: str = DEFAULT_OBJECTIVE, method: str = "auto",
         budget: int = DEFAULT_BUDGET, seed: int = 0, client=None, progress: bool = False,
         yours: np.ndarray | None = None, on_step: Step | None = None) -> TuneResult:
    """Every planned candidate scored, best first, beside the references, ``yours`` the printer's own
    parameters where known (see the module docstring); progress on ``on_step``, else tqdm bars on a
    terminal when ``progress``."""
    on_step = on_step or _steps(progress)
    cost = objective(objective_name)
    rules, optimisers = plan(method, problem.controller.pid)
    advance = on_step("the firmware's autotune, the references and the rules", 2) if on_step else None
    refs, notes = references(problem, cost, client, yours)
    if advance is not None:
        advance()
    gains, failures = rule_gains(problem, rules)
    notes += [f"rule {rule} gives no gains here: {why}" for rule, why in failures.items()]
    candidates = score(problem, cost, dict(gains), client) if gains else []
    if advance is not None:
        advance()
    if hopeless := hopeless_members(problem, [*refs, *candidates]):
        labels = ", ".join(problem.ensemble.members[k].label for k in hopeless) if problem.ensemble else ""
        problem = replace(problem, ensemble=without_members(problem.ensemble, hopeless))
        notes.append(f"left out of the ensemble: {labels}: every rule and reference trips on that plant (the corner of "
                     "what the data cannot pin down, not a printer any gains hold); the tune and its proof run without it")
        refs = score(problem, cost, {r.method: r.params for r in refs}, client)
        candidates = score(problem, cost, dict(gains), client) if gains else []
    if cost is heater_cost:  # scored against the reference to beat, from the runs already made
        cost = against(problem, reference_to_beat(refs))
        refs, candidates = rescored(problem, cost, refs), rescored(problem, cost, candidates)
    autotune = next((r.params for r in refs if r.method not in (DEFAULTS, YOURS)), None)
    start = autotune if autotune is not None or not candidates else candidates[0].params
    known = np.array([c.params for c in (*candidates, *refs)], float)
    for name in optimisers:
        candidates += search(problem, cost, name, search_bounds(problem, start), budget, seed, client, on_step,
                             known if len(known) else None, RUNNERS_UP)
    return TuneResult(problem, objective_name, sorted(candidates, key=lambda c: c.cost), refs, notes)


def _steps(progress: bool) -> Step | None:
    """tqdm bars on a terminal when ``progress``, else none."""
    if not progress:
        return None
    from tools.progress import Steps

    return Steps("bar")
