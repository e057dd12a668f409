"""python -m tools.seeds [SEED] [--budget small|paper|N] [--check] [--seeds 000,001,...] [--out FILE]

With a seed id (000 .. 004): re-run that paper's experiments under a progress bar (stderr) and print
each printed number beside ours with a verdict, which loop each number comes from, and the firmware
twin's numbers (tools/seeds/report.py); ``--budget`` sets how much its optimisers search.

Without one: re-run every paper at the small budget and write docs/seeds.md (tools/docs/seeds_page.py),
or, with --check, compare a fresh rendering with the committed page (words and verdicts exactly,
numbers within tools/validation/doc_compare.py's tolerance) and exit 1 if they differ. --seeds
renders (replacing those sections of an existing page) or checks those sections only.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tqdm import tqdm

from tools.cli.args import check_output, read_text_file
from tools.entry import EXIT_USAGE, INTERNAL_STATUS_HELP, OneLineParser, run_main
from tools.docs import seeds_page as page
from tools.seeds.command import BUDGET_HELP, run_seed
from tools.seeds.papers import PAPERS
from tools.seeds.report import SMALL_BUDGET, parse_budget
from tools.validation.doc_compare import compare_docs
from twin.limits import UserError

EXIT_STATUS = """exit status:
  0  the report printed, or the page written (or, with --check, current)
  1  --check: the page differs from a fresh rendering
  2  bad input (an option, an unwritable or missing page), said in one line
""" + INTERNAL_STATUS_HELP
DESCRIPTION = ("Re-run one seed paper and print it beside the paper's numbers, or (no SEED) write docs/seeds.md, "
               "or --check it is current.")


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.seeds", description=DESCRIPTION, epilog=EXIT_STATUS)
    parser.add_argument("seed", nargs="?", choices=list(PAPERS), help="a seed paper to re-run and print (no page)")
    parser.add_argument("--budget", type=parse_budget, help=BUDGET_HELP + "; with SEED only")
    parser.add_argument("--check", action="store_true", help="compare with the committed page instead of writing it")
    parser.add_argument("--seeds", help="comma-separated, e.g. 001,003 (default: all): the page's sections")
    parser.add_argument("--out", type=Path, help=f"the page (default {page.DOC.name} in docs/)")
    return parser


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.seed is not None and (args.check or args.seeds or args.out):
        parser.error("--check, --seeds and --out write or check the page: give them without SEED")
    if args.seed is None and args.budget is not None:
        parser.error("--budget: with SEED only (the page runs every seed at the small budget)")
    return args


def _progress_bar(seeds: list[str]) -> tqdm:
    return tqdm(total=sum(PAPERS[s].steps(SMALL_BUDGET) for s in seeds), desc="docs/seeds.md", unit="run",
                file=sys.stderr, leave=False)


def _render(seeds: list[str]) -> dict[str, str]:
    with _progress_bar(seeds) as bar:
        def progress(label: str) -> None:
            bar.set_postfix_str(label, refresh=False)
            bar.update()

        return page.sections(page.render(seeds, progress))


def _check(seeds: list[str], out: Path) -> int:
    committed = page.sections(out.read_text())
    fresh = _render(seeds)
    failed = 0
    for seed in seeds:
        if seed not in committed:
            print(f"seed {seed}: no section in {out}")
            failed += 1
            continue
        mismatches = compare_docs(fresh[seed], committed[seed])
        failed += bool(mismatches)
        print(f"seed {seed}: " + ("current" if not mismatches else f"{len(mismatches)} differences"))
        for mismatch in mismatches:
            print(f"  {mismatch}")
    return 1 if failed else 0


def _page(seeds: list[str], out: Path, check: bool) -> int:
    start_s = time.perf_counter()
    if check:
        status = _check(seeds, out)
    else:
        try:
            texts = page.sections(out.read_text()) if out.is_file() else {}
            texts.update(_render(seeds))  # a subset replaces its sections, keeps the rest
            out.write_text(page.assemble(texts))
        except OSError as error:
            print(f"tools.seeds: --out {out}: {error.strerror}", file=sys.stderr)
            return EXIT_USAGE
        print(f"wrote {out}")
        status = 0
    print(f"{len(seeds)} seeds in {time.perf_counter() - start_s:.0f} s")
    return status


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    if args.seed is not None:
        budget = args.budget or SMALL_BUDGET
        module = PAPERS[args.seed]
        return run_main("tools.seeds", lambda: run_seed(args.seed, module.report, module.steps(budget), budget))
    seeds = (args.seeds or ",".join(page.SECTIONS)).split(",")
    out = args.out or page.DOC
    unknown = [s for s in seeds if s not in page.SECTIONS]
    if unknown:
        print(f"tools.seeds: --seeds: unknown {unknown}, choose from {list(page.SECTIONS)}", file=sys.stderr)
        return EXIT_USAGE
    if args.check and not out.is_file():
        print(f"tools.seeds: --out {out}: no such file to check", file=sys.stderr)
        return EXIT_USAGE
    try:  # before the papers' runs: a page that cannot be written (or read, to check it) would lose them
        if not args.check:
            check_output(out)
        if out.exists():
            read_text_file(out)
    except UserError as exc:
        print(f"tools.seeds: --out {out}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return run_main("tools.seeds", lambda: _page(seeds, out, args.check))


if __name__ == "__main__":
    sys.exit(main())
