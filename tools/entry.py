"""The one way every command line parses and ends: a one-line error on a bad flag (``OneLineParser``), and
a result code, a one-line error on input it cannot use, quiet on a closed pipe (``run_main``).

argparse prints its usage block before an error; a user who typed one wrong flag needs one line
that names it (the project's rule for bad input), so ``OneLineParser.error`` prints only that. Library
modules with a ``python -m`` entry (tools/validation/golden.py, plant_check.py) use it too, so it lives
here rather than in tools/cli.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import NoReturn

EXIT_USAGE = 2  # argparse's own status for a usage error; ours for any input we cannot use


class OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line error (``prog: error: message``) and the epilog kept as written."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(**kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def run_main(prog: str, run: Callable[[], int], errors: tuple[type[BaseException], ...] = (ValueError,),
             describe: Callable[[BaseException], str] = str) -> int:
    """``run()``'s status; on one of ``errors`` (said by ``describe``) or another OSError (its file and
    reason), ``prog: error: ...`` on stderr and EXIT_USAGE; on a reader that left the pipe (``... | head``),
    0 and nothing more."""
    try:
        return run()
    except BrokenPipeError:
        sys.stdout = None  # nothing more can be written, not even at exit
        return 0
    except errors as exc:
        print(f"{prog}: error: {describe(exc)}", file=sys.stderr)
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
    return EXIT_USAGE


def run_cli(parser: argparse.ArgumentParser, run: Callable[[argparse.Namespace], int], argv: list[str] | None,
            errors: tuple[type[BaseException], ...] = (ValueError,)) -> int:
    """A whole ``main``: parse ``argv`` with ``parser`` (a bad flag exits 2), then ``run(args)`` under ``run_main``."""
    args = parser.parse_args(argv)
    return run_main(parser.prog, lambda: run(args), errors)

