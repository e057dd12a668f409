"""Compare a generated document with its committed copy: words, verdicts and integers exactly,
decimal numbers within a tolerance.

Why not byte for byte: docs/validation.md comes from least-squares fits whose last bits depend
on the BLAS kernel OpenBLAS picks at run time (Haswell, SkylakeX, ...), and closed-loop replays
through Klipper's pwm send rule (a change under 5 % of max_power is held back) turn a 1e-6
difference in a fitted parameter into a different sample being sent, which moves a printed
number in its third digit. The verdicts (pass/miss) and the counts of the summary do not move,
and they are compared exactly: a verdict that flips between machines is a finding, not noise.

Integers (targets, session numbers, counts such as 14/17, names like stm32f103) are compared
exactly; a number with a decimal point is compared as a number, within ``rel_tol`` of its size
or ``units`` steps of its last printed digit, whichever is larger.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from twin.limits import UserError

NUMBER_RE = re.compile(r"(?<![\w.])[-+]?\d+\.\d+(?![\w.])")  # a decimal number standing on its own
# Klipper sends a pwm change only when it exceeds 5 % of max_power (or at the resend interval), so a
# replay's sent pwm, and what it heats, can move by that much when a fit moves by a hair. Measured:
# docs/validation.md rendered with OPENBLAS_CORETYPE=Haswell, SkylakeX and Sandybridge differs in
# 6 numbers, at most 2.9 % (a twin's steady pwm 0.205 / 0.211) and 6 steps of the last digit.
REL_TOL = 0.05
UNITS = 3  # steps of the last printed digit: a 0.31 / 0.32 hold RMSE is a rounding step, not a change


@dataclass(frozen=True)
class Mismatch:
    """Where two documents differ beyond the tolerance: line number (1-based) and what differs."""

    line_no: int
    what: str

    def __str__(self) -> str:
        return f"line {self.line_no}: {self.what}"


def _close(new: str, old: str, rel_tol: float, units: float) -> bool:
    a, b = float(new), float(old)
    decimals = max(len(s.split(".")[1]) for s in (new, old))
    return abs(a - b) <= max(rel_tol * max(abs(a), abs(b)), units * 10.0 ** -decimals)


def compare_docs(new: str, old: str, rel_tol: float = REL_TOL, units: float = UNITS) -> list[Mismatch]:
    """The differences between two renderings beyond the tolerance (empty: the same document)."""
    new_lines, old_lines = new.splitlines(), old.splitlines()
    if len(new_lines) != len(old_lines):
        return [Mismatch(0, f"{len(new_lines)} lines against {len(old_lines)}")]
    out = []
    for no, (a, b) in enumerate(zip(new_lines, old_lines, strict=True), start=1):
        if NUMBER_RE.sub("#", a) != NUMBER_RE.sub("#", b):
            out.append(Mismatch(no, f"text differs: {a!r} against {b!r}"))
            continue
        for x, y in zip(NUMBER_RE.findall(a), NUMBER_RE.findall(b), strict=True):
            if not _close(x, y, rel_tol, units):
                out.append(Mismatch(no, f"{x} against {y}"))
    return out


def replace_section(text: str, body: str, begin: str, end: str) -> str | None:
    """``text`` with the lines between the markers ``begin...``/``end`` replaced, or None if absent
    (a generated section of a hand-written page: docs/tuning.md's tables)."""
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        return None
    head = text[: text.index("\n", start) + 1]
    return head + body.rstrip("\n") + "\n" + text[stop:]


def write_section(path: Path, body: str, begin: str, end: str) -> None:
    """Rewrite the file's generated section between the markers; ValueError if they are missing."""
    new = replace_section(path.read_text(), body, begin, end)
    if new is None:
        raise UserError(f"{path} lacks the '{begin} ... -->' / '{end}' markers")
    path.write_text(new)


def publish_section(body: str, doc: Path | None, begin: str, end: str) -> int:
    """A docs generator's output: the section rewritten in ``doc`` (if given) and printed; status 0."""
    if doc is not None:
        write_section(doc, body, begin, end)
    print(body)
    return 0
