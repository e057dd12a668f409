"""Running one seed paper from the command line: ``python -m tools.seeds 000 --budget small`` (and
``python -m tools.seeds.seed000``): its experiments under a progress bar on stderr, then its report
(tools/seeds/report.py) on stdout."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from tqdm import tqdm

from tools.entry import OneLineParser, run_main
from tools.seeds.report import SMALL_BUDGET, Budget, Progress, SeedReport, parse_budget, text

BUDGET_HELP = ("small (default: each seed's preset, under a minute), paper (the paper's own population and "
               "iterations: minutes to an hour for seeds 000 and 002) or N (the paper's population for N iterations)")
ReportFunction = Callable[[Budget, Progress], SeedReport[Any]]


def run_seed(seed: str, report: ReportFunction, steps: int, budget: Budget) -> int:
    """Run a seed's report under a progress bar, print it; 0."""
    with tqdm(total=steps, desc=f"seed {seed}", unit="run", file=sys.stderr, leave=False) as bar:
        def progress(label: str) -> None:
            bar.set_postfix_str(label, refresh=False)
            bar.update()

        result = report(budget, progress)
    print(text(result), end="")
    return 0


def main_for(seed: str, report: ReportFunction, steps: Callable[[Budget], int], argv: list[str] | None = None) -> int:
    """``python -m tools.seeds.seedNNN [--budget ...]``: the same as ``python -m tools.seeds NNN``."""
    parser = OneLineParser(prog=f"python -m tools.seeds.seed{seed}",
                           description=f"Re-run seed {seed}'s experiments and print them beside the paper's.")
    parser.add_argument("--budget", type=parse_budget, default=SMALL_BUDGET, help=BUDGET_HELP)
    args = parser.parse_args(argv)
    return run_main(parser.prog, lambda: run_seed(seed, report, steps(args.budget), args.budget))
