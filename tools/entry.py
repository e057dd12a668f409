"""The one way every command line parses and ends: a one-line error on a bad flag (``OneLineParser``), and
a result code, a one-line error on input it cannot use, quiet on a closed pipe, and a bug said to be one
(``run_main``).

Bad input is a ``UserError`` (twin/limits.py), raised where a flag, a file, a scenario or a capture is checked,
or an OSError (a path the user gave, a port taken: the machine refused): one line, exit 2. Anything else is a
bug in the twin, not the user's mistake: one line that says so and where its traceback was written
(``$XDG_STATE_HOME/heater-twin/``, else ``~/.local/state/heater-twin/``, else the temporary folder), exit 70
(EX_SOFTWARE in BSD's sysexits.h).

argparse prints its usage block before an error; a user who typed one wrong flag needs one line
that names it (the project's rule for bad input), so ``OneLineParser.error`` prints only that. Library
modules with a ``python -m`` entry (tools/validation/golden.py, plant_check.py) use it too, so it lives
here rather than in tools/cli.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from twin.limits import UserError

EXIT_USAGE = 2  # argparse's own status for a usage error; ours for any input we cannot use
EXIT_INTERNAL = 70  # EX_SOFTWARE (sysexits.h): an internal software error, never the user's input
REPORT_AT = "the heater-twin issue tracker"
# The lines of --help's "exit status:" block that every command shares (a command adds its own verdicts).
INTERNAL_STATUS_HELP = (f"  {EXIT_INTERNAL} an internal error (a bug, not your input): one line on stderr says so and names\n"
                        "     the file holding its traceback; please report it")
EXIT_STATUS_HELP = ("exit status:\n  0  done\n"
                    f"  {EXIT_USAGE}  bad input (an option or a file), said in one line on stderr; nothing is run\n"
                    + INTERNAL_STATUS_HELP)


class OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line error (``prog: error: message``) and the epilog kept as written."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
        super().__init__(**kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def run_main(prog: str, run: Callable[[], int], errors: tuple[type[BaseException], ...] = (UserError,),
             describe: Callable[[BaseException], str] = str) -> int:
    """``run()``'s status, with stdout line-buffered (a killed run keeps what it printed); on one of ``errors``
    (said by ``describe``) or an OSError (its file and reason), ``prog: error: ...`` on stderr and EXIT_USAGE;
    on a reader that left the pipe (``... | head``), 0 and nothing more; on anything else, ``internal_error``."""
    reconfigure = getattr(sys.stdout, "reconfigure", None)
    if reconfigure is not None:
        reconfigure(line_buffering=True)
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
    except Exception as exc:  # a bug: said to be one, never dressed as bad input
        return internal_error(prog, exc)
    return EXIT_USAGE


def internal_error(prog: str, exc: BaseException) -> int:
    """Write ``exc``'s traceback to a file, say so in one line on stderr; EXIT_INTERNAL."""
    what = " ".join(f"{type(exc).__name__}: {exc}".split())
    text = "".join(traceback.format_exception(exc))
    path = _traceback_file(prog, text)
    where = f"the traceback is in {path}" if path else "the traceback could not be written"
    print(f"{prog}: internal error: {what}; {where}; please report it at {REPORT_AT}", file=sys.stderr)
    return EXIT_INTERNAL


def _traceback_file(prog: str, text: str) -> Path | None:
    """A new file holding ``text`` in the user's state folder (else the temporary folder), named after the
    command (its last word: ``python -m tools.bench`` -> tools.bench-*); None if neither takes it."""
    state = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state") / "heater-twin"
    for folder in (state, Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            handle, name = tempfile.mkstemp(prefix=f"{prog.split()[-1]}-", suffix=".traceback.txt", dir=folder)
            with os.fdopen(handle, "w", encoding="utf-8") as file:
                file.write(text)
            return Path(name)
        except OSError:
            continue
    return None


def run_cli(parser: argparse.ArgumentParser, run: Callable[[argparse.Namespace], int], argv: list[str] | None,
            errors: tuple[type[BaseException], ...] = (UserError,)) -> int:
    """A whole ``main``: parse ``argv`` with ``parser`` (a bad flag exits 2), then ``run(args)`` under ``run_main``."""
    args = parser.parse_args(argv)
    return run_main(parser.prog, lambda: run(args), errors)

