"""The answer of a tune: new gains only where they beat the printer's own on every plant the log allows,
else "keep your gains".

A candidate beats the printer's gains (the reference) when, on every member of the ensemble, over the
proof's seeds (tools/tuning/proof.py; the worst seed counts):
- it never trips;
- its hold error is at most the reference's x HOLD_FACTOR + HOLD_SLACK_C (1.1 and 0.02 C: a tenth
  worse is within what a re-seated thermistor changes, 0.02 C within one reading's quantisation);
- its heat-up overshoot is at most the reference's + OVERSHOOT_SLACK_C (0.5 C);
and over the ensemble its heater objective (the mean over seeds, reduced by the ensemble's statistic) is
lower: it is better somewhere, not only no worse. A member on which the reference itself trips asks only
that the candidate does not. Duty chatter is reported, not bounded: the objective already charges it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tools.tuning.ensemble import Ensemble
from tools.tuning.proof import ProofRow

HOLD_FACTOR = 1.1
HOLD_SLACK_C = 0.02
OVERSHOOT_SLACK_C = 0.5
KEEP = "keep your gains"
NEW = "new gains"


def member_misses(candidate: ProofRow, reference: ProofRow) -> list[str]:
    """Why a candidate does not beat the reference on one member (empty: it does)."""
    if candidate.trips:
        return [f"trips in {candidate.trips} of {candidate.runs} runs"]
    if reference.trips:
        return []
    misses = []
    hold_bound = reference.hold_error_c[1] * HOLD_FACTOR + HOLD_SLACK_C
    if candidate.hold_error_c[1] > hold_bound:
        misses.append(f"hold {candidate.hold_error_c[1]:.3f} C > {hold_bound:.3f} C")
    overshoot_bound = reference.overshoot_c[1] + OVERSHOOT_SLACK_C
    if candidate.overshoot_c[1] > overshoot_bound:
        misses.append(f"overshoot {candidate.overshoot_c[1]:.2f} C > {overshoot_bound:.2f} C")
    return misses


def ensemble_cost(rows: Sequence[ProofRow], ensemble: Ensemble | None) -> float:
    """The heater objective over the members: each member's mean over seeds, reduced by the statistic."""
    costs = np.array([r.cost_s[0] for r in rows])
    return float(costs.mean()) if ensemble is None else float(ensemble.statistic_of(costs[:, None])[0])


@dataclass(frozen=True)
class Verdict:
    """The answer: ``kind`` NEW or KEEP, the method chosen (None: keep), the one-line why, and per member the
    reasons each candidate tried missed."""

    kind: str
    method: str | None
    why: str
    misses: dict[str, dict[str, list[str]]]  # candidate method -> member -> reasons

    @property
    def keep(self) -> bool:
        return self.kind == KEEP


def judge(rows: list[ProofRow], reference: str, order: Sequence[str], ensemble: Ensemble | None) -> Verdict:
    """The first candidate of ``order`` that beats the reference (the method named ``reference``) on every
    member and on the ensemble's cost, else keep your gains."""
    by = {(r.method, r.member): r for r in rows}
    members = list(dict.fromkeys(r.member for r in rows))
    ref_rows = [by[(reference, m)] for m in members]
    ref_cost = ensemble_cost(ref_rows, ensemble)
    misses: dict[str, dict[str, list[str]]] = {}
    for method in order:
        rows_c = [by[(method, m)] for m in members]
        missed = {m: why for m, c, r in zip(members, rows_c, ref_rows) if (why := member_misses(c, r))}
        cost = ensemble_cost(rows_c, ensemble)
        if not missed and cost >= ref_cost:
            missed = {"ensemble": [f"objective {cost:.4g} s not below yours {ref_cost:.4g} s"]}
        misses[method] = missed
        if not missed:
            return Verdict(NEW, method, gain_line(rows_c, ref_rows), misses)
    return Verdict(KEEP, None, keep_line(misses, ref_rows, len(members)), misses)


def _change(name: str, ours: float, yours: float, unit: str, digits: int = 2) -> str:
    if abs(ours - yours) < 0.5 * 10 ** -digits:
        return f"{name} unchanged ({yours:.{digits}f}{unit})"
    return f"{name} {yours:.{digits}f} -> {ours:.{digits}f}{unit}"


def gain_line(candidate: Sequence[ProofRow], reference: Sequence[ProofRow]) -> str:
    """What a user gains by changing, worst over members and seeds: overshoot, hold, chatter, trips."""
    def worst(rows: Sequence[ProofRow], attr: str) -> float:
        return max(getattr(r, attr)[1] for r in rows)

    def mean(rows: Sequence[ProofRow], attr: str) -> float:
        return float(np.mean([getattr(r, attr)[0] for r in rows]))

    parts = [_change("overshoot", worst(candidate, "overshoot_c"), worst(reference, "overshoot_c"), " C", 1),
             _change("hold", worst(candidate, "hold_error_c"), worst(reference, "hold_error_c"), " C")]
    chatter_c, chatter_r = mean(candidate, "chatter"), mean(reference, "chatter")
    if chatter_r > 0:
        parts.append(f"duty chatter {100.0 * (chatter_c / chatter_r - 1.0):+.0f} %")
    trips = sum(r.trips for r in reference)
    if trips:
        parts.append(f"trips {trips} -> 0")
    return f"{', '.join(parts)}, on all {len(candidate)} plants the log allows (worst seed)"


def keep_line(misses: dict[str, dict[str, list[str]]], reference: Sequence[ProofRow], n_members: int) -> str:
    """Why nothing beats the printer's gains, in one line: the closest candidate's misses."""
    if not misses:
        return "no candidate to try"
    method, missed = min(misses.items(), key=lambda kv: sum(len(v) for v in kv[1].values()))
    member, why = next(iter(missed.items()))
    more = f" (and on {len(missed) - 1} more)" if len(missed) > 1 else ""
    return (f"nothing beats them on every plant the log allows: the closest, {method}, misses on {member}: "
            f"{'; '.join(why)}{more}")
