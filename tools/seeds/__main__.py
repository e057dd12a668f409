"""python -m tools.seeds [--check] [--seeds 000,001,...] [--out FILE]: re-run every seed paper's headline
experiments and write docs/seeds.md (tools/seeds/page.py), or, with --check, compare a fresh rendering
with the committed page (words and verdicts exactly, numbers within tools/validation/doc_compare.py's
tolerance) and exit 1 if they differ. --seeds renders (replacing those sections of an existing page)
or checks those sections only."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tools.seeds import page
from tools.validation.doc_compare import compare_docs

DESCRIPTION = "Re-run the seed papers' experiments and write docs/seeds.md, or --check it is current."


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m tools.seeds", description=DESCRIPTION)
    parser.add_argument("--check", action="store_true", help="compare with the committed page instead of writing it")
    parser.add_argument("--seeds", default=",".join(page.SECTIONS), help="comma-separated, e.g. 001,003 (all)")
    parser.add_argument("--out", type=Path, default=page.DOC, help=f"the page (default {page.DOC.name} in docs/)")
    return parser.parse_args(argv)


def _check(seeds: list[str], out: Path) -> int:
    committed = page.sections(out.read_text())
    fresh = page.sections(page.render(seeds))
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


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    seeds = args.seeds.split(",")
    unknown = [s for s in seeds if s not in page.SECTIONS]
    if unknown:
        print(f"tools.seeds: --seeds: unknown {unknown}, choose from {list(page.SECTIONS)}", file=sys.stderr)
        return 2
    if args.check and not args.out.is_file():
        print(f"tools.seeds: --out {args.out}: no such file to check", file=sys.stderr)
        return 2
    start_s = time.perf_counter()
    if args.check:
        status = _check(seeds, args.out)
    else:
        try:
            texts = page.sections(args.out.read_text()) if args.out.is_file() else {}
            texts.update(page.sections(page.render(seeds)))  # a subset replaces its sections, keeps the rest
            args.out.write_text(page.assemble(texts))
        except OSError as error:
            print(f"tools.seeds: --out {args.out}: {error.strerror}", file=sys.stderr)
            return 2
        print(f"wrote {args.out}")
        status = 0
    print(f"{len(seeds)} seeds in {time.perf_counter() - start_s:.0f} s")
    return status


if __name__ == "__main__":
    sys.exit(main())
