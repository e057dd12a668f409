"""The golden M306 T transcript: Marlin's MPC autotune on the default virtual printer with MPC
(``twin-serial --firmware mpc --plant hotend``: the ``hotend`` preset, which is Marlin's MPC model, so
that the constants M306 T finds can be checked against the plant's own, and the default bed).

``python -m tools.validation.golden_m306 --write`` records what the printer answers to ``M306 T``
into tests/golden/m306_autotune.txt; tests/protocol/test_m306_pty.py sends the same line to
twin-serial over a pseudo-terminal and compares line by line, exactly: the run is a function of
the bytes sent (an integer firmware clock, the float32 law, a host-driven clock while idle).
Regenerate only on purpose, after a deliberate change of behaviour, and review the diff.
"""

from __future__ import annotations

from pathlib import Path

from protocol.build import build_printer
from tools.entry import OneLineParser
from tools.validation.golden import golden_cli, golden_parser

GOLDEN_M306_PATH = Path(__file__).resolve().parents[2] / "tests" / "golden" / "m306_autotune.txt"
COMMAND = "M306 T"
FIRMWARE = "mpc"
PLANT_PRESET = "hotend"  # Marlin's MPC model (twin/plants.py): M306 T's answer has a known truth


def record_m306() -> list[str]:
    """The printer's lines from ``M306 T`` to its ``ok``, right after boot."""
    printer = build_printer(firmware=FIRMWARE, plant=PLANT_PRESET)
    printer.take_output()  # the banner
    printer.receive(COMMAND.encode() + b"\n")
    printer.run_until_idle()
    return printer.take_output().decode().splitlines()


PROG = "python -m tools.validation.golden_m306"


def build_parser() -> OneLineParser:
    return golden_parser(PROG, __doc__.splitlines()[0], GOLDEN_M306_PATH)


def main(argv: list[str] | None = None) -> int:
    return golden_cli(PROG, __doc__.splitlines()[0], GOLDEN_M306_PATH, record_m306, argv)


if __name__ == "__main__":
    raise SystemExit(main())
