"""What a seed paper's re-run reports: each printed number beside ours with a verdict, which loop each
number comes from, the budget it ran at, and the firmware twin's numbers; as terminal text
(``python -m tools.seeds 000``) or markdown (docs/seeds.md). The seed modules fill it in.

Verdicts:
- ``reproduced``: ours agrees with the printed number within the stated tolerance, and nothing in
  our run was fitted to that number (a re-run listing or a prediction);
- ``fitted``: ours agrees because one of our parameters was chosen to make it agree (the reason
  names the parameter): consistency, not a reproduction;
- ``differs``: ours does not agree; the reason says why, from what was computed;
- ``impossible``: no correct run can print this number; the reason gives the evidence.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Generic, TypeVar

REPRODUCED, FITTED, DIFFERS, IMPOSSIBLE = "reproduced", "fitted", "differs", "impossible"
VERDICTS = (REPRODUCED, FITTED, DIFFERS, IMPOSSIBLE)
DIVERGED = 1e6  # a figure beyond this comes from a loop that blew up: "diverges", not its digits

SMALL, PAPER = "small", "paper"


@dataclass(frozen=True)
class Budget:
    """How much search a seed's optimisers get: ``small`` (its preset, under a minute), ``paper``
    (the paper's own settings) or N (the paper's population for N iterations or generations)."""

    name: str
    iterations: int | None = None

    def __str__(self) -> str:
        return self.name if self.iterations is None else f"{self.iterations} iterations"


SMALL_BUDGET, PAPER_BUDGET = Budget(SMALL), Budget(PAPER)


def parse_budget(text: str) -> Budget:
    """``--budget``: small, paper or a whole number of iterations >= 3 (an argparse type)."""
    if text in (SMALL, PAPER):
        return Budget(text)
    if text.isdigit() and int(text) >= 3:
        return Budget("iterations", int(text))
    raise argparse.ArgumentTypeError(f"expected small, paper or a number of iterations >= 3, not {text!r}")


Progress = Callable[[str], None]  # called once after each experiment, with what it ran


def no_progress(_label: str) -> None:
    """A Progress that shows nothing (the page generator, tests)."""


@dataclass(frozen=True)
class Verdict:
    """One printed number (or claim) beside ours."""

    experiment: str  # where it is printed, e.g. "table 1, PID"
    quantity: str  # what it is, with its unit
    printed: str  # as printed
    ours: str  # ours, formatted
    verdict: str  # one of VERDICTS
    why: str  # the tolerance, the fitted parameter, the reason or the evidence
    claim: bool = False  # a claim in the paper's words (X beats Y), not one of its numbers

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {', '.join(VERDICTS)}, not {self.verdict!r}")


@dataclass(frozen=True)
class Table:
    """A table of numbers with no printed counterpart (the firmware twin's), with its caption."""

    caption: str
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


T = TypeVar("T")


@dataclass(frozen=True)
class SeedReport(Generic[T]):
    """A seed's re-run: its verdicts, the loops its numbers come from, and the raw result."""

    seed: str
    title: str
    budget: str  # in words
    loops: tuple[str, ...]  # one sentence per loop used: what it is and whether a firmware delay is in it
    verdicts: tuple[Verdict, ...]
    result: T
    tables: tuple[Table, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)  # computed evidence, in sentences

    def counts(self) -> dict[str, int]:
        return {v: sum(row.verdict == v for row in self.verdicts) for v in VERDICTS}


def num(value: float | None, decimals: int = 2) -> str:
    """A computed number with a decimal point (the page comparison treats it as a number), '-' for None."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if abs(value) > DIVERGED:
        return "diverges"
    return f"{value:.{decimals}f}"


def within(ours: float | None, printed: float, tolerance: float) -> bool:
    """ours is a number and lies within tolerance (absolute) of printed."""
    return ours is not None and math.isfinite(ours) and abs(ours - printed) <= tolerance


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def text_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """Columns padded to their widest cell, the last one left ragged."""
    rows = [list(header), *map(list, rows)]
    widths = [max(len(row[i]) for row in rows) for i in range(len(header) - 1)]
    return "\n".join("  ".join([*(cell.ljust(w) for cell, w in zip(row, widths)), row[-1]]).rstrip()
                     for row in rows)


VERDICT_HEADER = ("experiment", "quantity", "printed", "ours", "verdict")


def verdict_cells(row: Verdict) -> tuple[str, ...]:
    return row.experiment, row.quantity, row.printed, row.ours, f"{row.verdict}: {row.why}"


def summary(report: SeedReport) -> str:
    counts = report.counts()
    return ", ".join(f"{n} {v}" for v, n in counts.items() if n) + f" (of {len(report.verdicts)})"


def text(report: SeedReport) -> str:
    """The terminal form: title, budget, loops, the verdicts, the twin's tables, the notes."""
    parts = [f"Seed {report.seed}: {report.title}", f"budget: {report.budget}",
             "loops:\n" + "\n".join(f"  - {loop}" for loop in report.loops),
             text_table(VERDICT_HEADER, map(verdict_cells, report.verdicts)),
             f"verdicts: {summary(report)}"]
    parts += [f"{t.caption}\n{text_table(t.header, t.rows)}" for t in report.tables]
    if report.notes:
        parts.append("notes:\n" + "\n".join(f"  - {note}" for note in report.notes))
    return "\n\n".join(parts) + "\n"


def markdown_verdicts(report: SeedReport) -> str:
    """The page's verdict table and its count."""
    table = markdown_table(("experiment", "quantity", "printed", "ours", "verdict", "why"),
                           ([r.experiment, r.quantity, r.printed, r.ours, r.verdict, r.why] for r in report.verdicts))
    return f"{table}\n\nVerdicts: {summary(report)}."
