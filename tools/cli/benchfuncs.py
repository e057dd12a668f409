"""python -m tools.cli.benchfuncs: every optimiser on F1-F23 (tools/tuning/benchfuncs.py) in the forms
asked for, as a markdown report (tools/tuning/optim/benchmark.py) with seed 002's printed ALO/OCALO
tables beside ours (tools/seeds/seed002_benchmark.py); ``--doc docs/tuning.md`` rewrites that page's
generated section. A progress bar on stderr counts the runs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tqdm import tqdm

from tools.seeds import seed002_benchmark
from tools.tuning.benchfuncs import BENCHMARKS, BY_NAME, FORMS, PLAIN
from tools.tuning.optim import METHODS
from tools.tuning.optim.benchmark import SEED_ITERATIONS, SEED_POPULATION, format_report, run_all, tasks_for
from tools.cli.args import check_output, section_page
from tools.entry import OneLineParser, run_main
from twin.limits import UserError
from tools.validation.doc_compare import replace_section

PROG = "python -m tools.cli.benchfuncs"
QUICK = {"runs": 2, "population": 10, "iterations": 10}  # --quick: a smoke run of every pair
DOC_BEGIN, DOC_END = "<!-- benchfuncs: begin", "<!-- benchfuncs: end -->"


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog=PROG, description="Every optimiser on F1-F23, as a markdown report.")
    parser.add_argument("--runs", type=int, default=30,
                        help="runs per function, optimiser and form (default: %(default)s)")
    parser.add_argument("--population", type=int, default=SEED_POPULATION,
                        help="population (default: %(default)s, seed 002's)")
    parser.add_argument("--iterations", type=int, default=SEED_ITERATIONS,
                        help="iterations; budget = population x this (default: %(default)s, seed 002's)")
    parser.add_argument("--seed", type=int, default=0, help="root seed of every run's Generator (default: %(default)s)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (default: %(default)s)")
    parser.add_argument("--methods", default="nm,de,pso,alo,ocalo",
                        help=f"comma-separated, of {','.join(METHODS)} (default: %(default)s)")
    parser.add_argument("--functions", default=",".join(b.name for b in BENCHMARKS),
                        help="comma-separated, e.g. F1,F9,F21 (default: %(default)s)")
    parser.add_argument("--forms", default=PLAIN, help=f"comma-separated, of {','.join(FORMS)} "
                        "(shifted/rotated: F1-F7, F9-F13 only; default plain)")
    parser.add_argument("--quick", action="store_true", help="2 runs, population 10, 10 iterations")
    parser.add_argument("--out", type=Path, help="write the markdown report here (default: stdout)")
    parser.add_argument("--doc", type=Path, help="rewrite the report's section of this markdown file (docs/tuning.md)")
    return parser


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    args = build_parser().parse_args(argv)
    if args.quick:
        vars(args).update(QUICK)
    return args


def _problem(args: argparse.Namespace) -> str | None:
    """The first bad flag, as a one-line message, or None."""
    unknown_methods = [m for m in args.methods.split(",") if m not in METHODS]
    unknown_functions = [f for f in args.functions.split(",") if f not in BY_NAME]
    unknown_forms = [f for f in args.forms.split(",") if f not in FORMS]
    checks = [
        (args.runs < 1, "--runs must be >= 1"),
        (args.population < 5, "--population must be >= 5 (DE needs 5)"),
        (args.iterations < 3, "--iterations must be >= 3 (OCALO's start costs 2 populations)"),
        (args.workers < 1, "--workers must be >= 1"),
        (args.seed < 0, "--seed must be >= 0"),
        (bool(unknown_methods), f"--methods: unknown {unknown_methods}, choose from {sorted(METHODS)}"),
        (bool(unknown_functions), f"--functions: unknown {unknown_functions}, choose from F1..F23"),
        (bool(unknown_forms), f"--forms: unknown {unknown_forms}, choose from {list(FORMS)}"),
    ]
    return next((message for bad, message in checks if bad), None)


def _write_out(path: Path, report: str) -> str | None:
    try:
        path.write_text(report)
    except OSError as error:
        return str(error.strerror)
    return None


def _write_doc(path: Path, report: str, command: str) -> str | None:
    """Rewrite the section between the benchfuncs markers, stating the command that wrote it."""
    try:
        text = path.read_text()
    except OSError as error:
        return str(error.strerror)
    new = replace_section(text, f"Written by `{PROG} {command}`.\n\n{report}", DOC_BEGIN, DOC_END)
    if new is None:
        return f"no '{DOC_BEGIN} ... -->' / '{DOC_END}' markers"
    return _write_out(path, new)


def report(args: argparse.Namespace) -> str:
    """Run the benchmark the flags ask for; our tables, then seed 002's beside ours."""
    methods, functions, forms = args.methods.split(","), args.functions.split(","), args.forms.split(",")
    settings = {"seed": args.seed, "population": args.population, "iterations": args.iterations}
    total = len(tasks_for(functions, methods, args.runs, forms=forms, **settings))
    start_s = time.perf_counter()
    with tqdm(total=total, desc="runs", unit="run", file=sys.stderr, leave=False) as bar:
        results = run_all(functions, methods, args.runs, workers=args.workers, forms=forms, progress=bar.update,
                          **settings)
    text = format_report(results, methods, runs=args.runs, population=args.population, iterations=args.iterations,
                         wall_s=time.perf_counter() - start_s, workers=args.workers)
    if {"alo", "ocalo"} <= set(methods):
        text += "\n" + seed002_benchmark.benchmark_report(results, args.runs)
    return text


def run(args: argparse.Namespace, command: str) -> int:
    problem = _problem(args)
    if problem:
        raise UserError(problem)
    for flag, path, check in (("--out", args.out, check_output),  # before the runs: a typo costs nothing
                              ("--doc", args.doc, lambda page: section_page(page, DOC_BEGIN, DOC_END))):
        try:
            if path is not None:
                check(path)
        except ValueError as exc:
            raise UserError(f"{flag} {path}: {exc}") from None
    text = report(args)
    if args.out is None and args.doc is None:
        print(text, end="")
        return 0
    for flag, path in (("--out", args.out), ("--doc", args.doc)):
        if path is None:
            continue
        problem = _write_out(path, text) if flag == "--out" else _write_doc(path, text, command)
        if problem:
            raise UserError(f"{flag} {path}: {problem}")
        print(f"report written to {path}")
    print(text.split("\n\n")[0])
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    return run_main(PROG, lambda: run(args, " ".join(sys.argv[1:] if argv is None else argv)))


if __name__ == "__main__":
    sys.exit(main())
