"""Every optimiser on F1-F23 (tools/tuning/benchfuncs.py), in their plain, shifted and rotated forms,
and the markdown tables of what they found.

Seed 002 (the OCALO paper, section 3) runs each algorithm with a population of 50 for 300
iterations and prints the mean, best and worst over its runs. Here every optimiser gets the same
budget, population x iterations objective evaluations, so Nelder-Mead (no population) and OCALO
(whose start evaluates 2 populations) are compared at equal cost.

The shifted and rotated forms move each scalable function's minimum away from the origin and
off the box's diagonal (``benchfuncs.variant``): an optimiser that is pulled towards the origin
(OCALO's cosine factors, see ocalo.py) finds the plain F1-F4, F6, F7, F9-F11 minima by that pull
and not by searching; the other forms show what it finds when the pull leads nowhere.

Each run draws from its own Generator seeded by (seed, function, method, run): the numbers do not
depend on how runs are spread over worker processes, and a function's forms share the search's
random numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from tools.tuning.benchfuncs import BENCHMARKS, BY_NAME, MOVABLE, PLAIN, variant
from tools.tuning.optim import METHODS

SEED_POPULATION, SEED_ITERATIONS = 50, 300  # seed 002, section 3.1
POPULATION_METHODS = ("de", "pso", "alo", "ocalo")  # take a ``population`` option

Results = dict[tuple[str, str, str], np.ndarray]  # (function, method, form) -> best cost of each run


@dataclass(frozen=True)
class Task:
    function: str
    method: str
    run: int
    seed: int
    population: int
    iterations: int
    form: str = PLAIN


def run_task(task: Task) -> float:
    """Best cost of one run of one optimiser on one function in one form."""
    bench = variant(task.function, task.form)
    keys = [task.seed, BENCHMARKS.index(BY_NAME[task.function]), sorted(METHODS).index(task.method), task.run]
    search_rng, noise_rng = np.random.default_rng(keys).spawn(2)
    options = {"population": task.population} if task.method in POPULATION_METHODS else {}
    result = METHODS[task.method](
        lambda points: bench.costs(points, noise_rng),
        bench.bounds,
        rng=search_rng,
        budget=task.population * task.iterations,
        **options,
    )
    return result.cost


def tasks_for(functions: Sequence[str], methods: Sequence[str], runs: int, *, seed: int, population: int,
              iterations: int, forms: Sequence[str] = (PLAIN,)) -> list[Task]:
    """Every run of the benchmark, each function in each of ``forms`` where that form is defined."""
    return [Task(f, m, r, seed, population, iterations, form) for form in forms for f in functions
            if form == PLAIN or f in MOVABLE for m in methods for r in range(runs)]


def run_all(
    functions: Sequence[str], methods: Sequence[str], runs: int, *, seed: int, population: int,
    iterations: int, workers: int, forms: Sequence[str] = (PLAIN,), progress: Callable[[int], None] | None = None,
) -> Results:  # fmt: skip
    """Best cost of each run, keyed by (function, method, form); ``progress(n)`` after each n runs done."""
    tasks = tasks_for(functions, methods, runs, seed=seed, population=population, iterations=iterations, forms=forms)
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            costs = []
            for cost in pool.map(run_task, tasks, chunksize=max(1, len(tasks) // (8 * workers))):
                costs.append(cost)
                if progress:
                    progress(1)
    else:
        costs = []
        for task in tasks:
            costs.append(run_task(task))
            if progress:
                progress(1)
    table: dict[tuple[str, str, str], list[float]] = {}
    for task, cost in zip(tasks, costs, strict=True):
        table.setdefault((task.function, task.method, task.form), []).append(cost)
    return {key: np.array(values) for key, values in table.items()}


def fmt_g(value: float) -> str:
    """A cost for a table: 4 significant digits, scientific below 1e-3."""
    return f"{value:.4g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.3e}"


def forms_of(results: Results) -> list[str]:
    return list(dict.fromkeys(form for _, _, form in results))


def ours_table(results: Results, methods: Sequence[str], form: str = PLAIN) -> list[str]:
    """Markdown rows: each function in ``form``, best / mean / std of each method over its runs."""
    header = "| F | dims | range | known min | " + " | ".join(f"{m} best / mean / std" for m in methods) + " |"
    lines = [header, "|" + "---|" * (4 + len(methods))]
    for bench in BENCHMARKS:
        if (bench.name, methods[0], form) not in results:
            continue
        cells = []
        for method in methods:
            costs = results[bench.name, method, form]
            spread = costs.std(ddof=1) if costs.size > 1 else 0.0
            cells.append(f"{fmt_g(costs.min())} / {fmt_g(costs.mean())} / {fmt_g(spread)}")
        span = f"[{bench.low:g}, {bench.high:g}]"
        lines.append(f"| {bench.name} {bench.title} | {bench.dims} | {span} | {fmt_g(bench.minimum)} | "
                     + " | ".join(cells) + " |")
    return lines


def means_by_form(results: Results, methods: Sequence[str]) -> list[str]:
    """Markdown rows: the functions that have other forms, each method's mean in every form side by side."""
    forms = forms_of(results)
    header = "| F | " + " | ".join(f"{m} {form}" for m in methods for form in forms) + " |"
    lines = [header, "|" + "---|" * (1 + len(methods) * len(forms))]
    for name in MOVABLE:
        if not all((name, m, form) in results for m in methods for form in forms):
            continue
        cells = [fmt_g(results[name, m, form].mean()) for m in methods for form in forms]
        lines.append(f"| {name} {BY_NAME[name].title} | " + " | ".join(cells) + " |")
    return lines


def wins(results: Results, method: str, other: str, form: str) -> tuple[int, int]:
    """On how many functions (of those run in ``form``) ``method``'s mean is below ``other``'s."""
    names = [b.name for b in BENCHMARKS if (b.name, method, form) in results and (b.name, other, form) in results]
    won = sum(results[n, method, form].mean() < results[n, other, form].mean() for n in names)
    return int(won), len(names)


def best_by_mean(results: Results, methods: Sequence[str], function: str, form: str) -> str:
    """The method with the lowest mean on one function in one form."""
    return min(methods, key=lambda m: results[function, m, form].mean())


def pull_summary(results: Results, methods: Sequence[str]) -> list[str]:
    """Sentences, from the numbers: how each method's means move when the minima leave the origin."""
    forms = forms_of(results)
    moved = [form for form in forms if form != PLAIN]
    if PLAIN not in forms or not moved:
        return []
    lines = []
    if "F1" in {f for f, _, _ in results}:
        for method in methods:
            path = " -> ".join(f"{fmt_g(results['F1', method, form].mean())} ({form})" for form in forms)
            lines.append(f"F1 (Sphere), {method} mean: {path}")
    movable = [n for n in MOVABLE if all((n, m, form) in results for m in methods for form in forms)]
    for form in forms:
        leaders = [best_by_mean(results, methods, n, form) for n in movable]
        counts = ", ".join(f"{m} {leaders.count(m)}" for m in methods if leaders.count(m))
        lines.append(f"lowest mean on the {len(movable)} functions that have every form, {form}: {counts}")
    return lines


def format_report(
    results: Results, methods: Sequence[str], *, runs: int, population: int, iterations: int, wall_s: float,
    workers: int,
) -> str:  # fmt: skip
    """Our tables: each form's best / mean / std, the means side by side, and what moves with the minima."""
    forms = forms_of(results)
    out = [
        f"Every optimiser on F1-F23: population {population}, {iterations} iterations, budget "
        f"{population * iterations} evaluations per run, {runs} runs; {wall_s:.0f} s wall on {workers} worker(s). "
        f"Forms: {', '.join(forms)}.",
    ]
    for form in forms:
        out += ["", f"{form.capitalize()} form:", "", *ours_table(results, methods, form)]
    if len(forms) > 1:
        out += ["", "Means of the functions that have every form, side by side:", "", *means_by_form(results, methods)]
        out += ["", *[f"- {line}" for line in pull_summary(results, methods)]]
    return "\n".join(out) + "\n"
