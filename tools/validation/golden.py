"""The golden serial session: a scripted exchange with the default virtual printer.

``python -m tools.validation.golden --write`` records it into tests/golden/marlin_session.txt; the test
replays the same script and compares the transcript line by line. Regenerate only on purpose,
after a deliberate change of behaviour, and review the diff.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from protocol.lines import with_checksum
from protocol.printer import VirtualPrinter
from twin.build import build_twin
from twin.scenario import parse_scenario
from tools.entry import OneLineParser, run_main

PROG = "python -m tools.validation.golden"
GOLDEN_PATH = Path(__file__).resolve().parents[2] / "tests" / "golden" / "marlin_session.txt"
SERIAL_SCENARIO = 'duration_s = 86400\nname = "golden"\n'


def _bad_checksum(line: str) -> str:
    head, cs = line.rsplit("*", 1)
    return f"{head}*{(int(cs) + 1) % 256}"


SCRIPT = (
    "M115",
    "M105",
    with_checksum("M110 N0", 0),
    with_checksum("M104 S200", 1),
    with_checksum("M109 S200", 2),
    with_checksum("M303 E0 S210 C8", 3),
    _bad_checksum(with_checksum("M105", 4)),
    with_checksum("M105", 4),
    "M112",
    "M105",
)


def record_session() -> list[str]:
    """Run SCRIPT at --speed max; ``< `` lines are the printer's, ``> `` lines the host's."""
    printer = VirtualPrinter(lambda: build_twin(parse_scenario(SERIAL_SCENARIO, "golden"), "pid"))
    transcript = [f"< {line}" for line in printer.take_output().decode().splitlines()]
    for line in SCRIPT:
        transcript.append(f"> {line}")
        printer.receive(line.encode() + b"\n")
        printer.run_until_idle()
        transcript += [f"< {reply}" for reply in printer.take_output().decode().splitlines()]
    return transcript


def golden_cli(prog: str, description: str, path: Path, record: Callable[[], list[str]],
               argv: list[str] | None) -> int:
    """A golden transcript's command: print what ``record`` gives, or with --write keep it in ``path``."""
    args = golden_parser(prog, description, path).parse_args(argv)

    def run() -> int:
        text = "\n".join(record()) + "\n"
        if args.write:
            path.write_text(text)
            print(f"wrote {path} ({text.count(chr(10))} lines)")
        else:
            print(text, end="")
        return 0

    return run_main(prog, run)


def golden_parser(prog: str, description: str, path: Path) -> OneLineParser:
    parser = OneLineParser(prog=prog, description=description)
    parser.add_argument("--write", action="store_true", help=f"rewrite {path}")
    return parser


def build_parser() -> OneLineParser:
    return golden_parser(PROG, __doc__.splitlines()[0], GOLDEN_PATH)


def main(argv: list[str] | None = None) -> int:
    return golden_cli(PROG, __doc__.splitlines()[0], GOLDEN_PATH, record_session, argv)


if __name__ == "__main__":
    raise SystemExit(main())
