"""Tables as the generated docs write them (markdown) and as a terminal shows them (plain text,
split into several tables of at most WIDTH columns, the key columns repeated in each)."""

from __future__ import annotations

from collections.abc import Sequence

WIDTH = 120  # a terminal's line: the CLIs keep their output within it


def markdown_table(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A markdown table: header, rule, rows."""
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)] + ["| " + " | ".join(r) + " |"
                                                                             for r in rows]


def markdown_cells(row: str) -> list[str]:
    """The cells of a markdown table row ("| a | b |")."""
    return [cell.strip() for cell in row.strip().strip("|").split("|")]


def text_tables(columns: Sequence[str], rows: Sequence[Sequence[str]], keys: int = 1, width: int = WIDTH,
                drop: Sequence[str] = ()) -> list[str]:
    """Plain aligned tables within ``width`` columns: as many of the other columns as fit beside the
    first ``keys`` columns, then the next ones beside them again; columns named in ``drop`` left out.
    A cell wider than the line is kept whole (it stands alone beside the keys)."""
    keep = [i for i, name in enumerate(columns) if name not in drop]
    cells = [[str(columns[i]) for i in keep]] + [[str(r[i]) if i < len(r) else "" for i in keep] for r in rows]
    widths = [max(len(row[j]) for row in cells) for j in range(len(keep))]
    key_width = sum(widths[:keys]) + 2 * keys
    out: list[str] = []
    j = keys
    while j < len(keep) or j == keys:
        group: list[int] = []
        used = key_width
        while j < len(keep) and (not group or used + widths[j] + 2 <= width):
            group.append(j)
            used += widths[j] + 2
            j += 1
        chosen = list(range(keys)) + group
        if out:
            out.append("")
        for k, row in enumerate(cells):
            out.append("  ".join(row[c].ljust(widths[c]) for c in chosen).rstrip())
            if k == 0:
                out.append("  ".join("-" * widths[c] for c in chosen))
        if not group:
            break
    return out
