"""The one way every CLI ends: a result code, a one-line error on bad input, quiet on a closed pipe."""

from __future__ import annotations

import sys
from collections.abc import Callable

EXIT_USAGE = 2  # argparse's own status for a usage error; ours for any input we cannot use


def run_main(prog: str, run: Callable[[], int], errors: tuple[type[BaseException], ...] = (ValueError,),
             describe: Callable[[BaseException], str] = str) -> int:
    """``run()``'s status; on one of ``errors`` or an OSError, ``prog: error: ...`` on stderr and EXIT_USAGE;
    on a reader that left the pipe (``... | head``), 0 and nothing more."""
    try:
        return run()
    except BrokenPipeError:
        sys.stdout = None  # nothing more can be written, not even at exit
        return 0
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
    except errors as exc:
        print(f"{prog}: error: {describe(exc)}", file=sys.stderr)
    return EXIT_USAGE
