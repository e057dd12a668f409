"""What the quick proof of edited gains shows, in one line beside the answer's own proof.

twin-tune proves the edited gains as the gains to beat (tuner.QUICK) on the plants the capture allows, with the
noise seeds of the answer's proof: its rows for "yours" are the edit's, comparable row for row with the answer's
and the printer's rows of the answer (docs/octoprint.md). The tab states what they show; an edit that trips
thermal protection on any plant is not applied (the twin applies no gains it saw trip).
"""

from __future__ import annotations

from octoprint_heater_twin.console import Gains

YOURS, ANSWER = "yours", "answer"  # the proof rows' candidates: the gains to beat, the answer


def _rows(document: dict, candidate: str) -> list[dict]:
    return [row for row in document.get("proof") or [] if row["candidate"] == candidate]


def _worst(rows: list[dict], field: str) -> float | None:
    return max(row[field][1] for row in rows) if rows else None


def _c(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} C"


def summary(edited: Gains, check: dict, answer: dict) -> dict:
    """The check as the tab keeps it: the edited gains, the edit's rows, whether it trips, and its line."""
    rows = _rows(check, YOURS)
    if not rows:
        return {"gains": edited._asdict(), "rows": [], "trips": True,
                "line": "The twin did not prove the edited gains (no proof rows in its answer): not applied"}
    tripped = [f"{row['member']} in {row['trips']} of {row['runs']} runs" for row in rows if row["trips"]]
    if tripped:
        line = (f"{edited.text()} trips thermal protection on the twin ({', '.join(tripped)}): not applied (the "
                "twin applies no gains it saw trip)")
    else:
        theirs = [_rows(answer, ANSWER), _rows(answer, YOURS)]
        runs = rows[0]["runs"]
        reference = "your printer's" if answer.get("current") else "the firmware's autotune's"
        line = (f"{edited.text()} never trips on the {len(rows)} plant{'s' if len(rows) > 1 else ''} the capture "
                f"allows ({runs} runs each): worst overshoot {_c(_worst(rows, 'overshoot_c'))} (the answer "
                f"{_c(_worst(theirs[0], 'overshoot_c'))}, {reference} {_c(_worst(theirs[1], 'overshoot_c'))}), "
                f"worst hold error {_c(_worst(rows, 'hold_error_c'))} ({_c(_worst(theirs[0], 'hold_error_c'))}, "
                f"{_c(_worst(theirs[1], 'hold_error_c'))})")
    return {"gains": edited._asdict(), "rows": rows, "trips": bool(tripped), "line": line}
