"""The answer of a tune: new gains only where they beat the printer's own on every plant the log allows,
else "keep your gains".

A candidate beats the printer's gains (the reference) when, on every member of the ensemble, over the
proof's seeds (tools/tuning/proof.py; the worst seed counts):
- it never trips;
- its hold error is at most the reference's x HOLD_FACTOR + HOLD_SLACK_C (1.1 and 0.02 C: a tenth
  worse is within what a re-seated thermistor changes, 0.02 C within one reading's quantisation);
- its heat-up overshoot is at most the reference's + OVERSHOOT_SLACK_C (0.5 C);
and over the ensemble its heater objective (the mean over seeds, reduced by the ensemble's statistic) is
at least MIN_GAIN_REL (5 %) lower: a change must buy something a user would notice, beyond the twin's
own fidelity (docs/validation.md: heat-up times within 10 %), not only be no worse. A member on which the reference itself trips asks only
that the candidate does not. Duty chatter is reported, not bounded: the objective already charges it.

Of the candidates that beat the reference, the answer is the first (the search's cheapest) unless another
holds as well (worst hold within x HOLD_FACTOR + HOLD_SLACK_C of the first's) and overshoots less by more
than OVERSHOOT_SLACK_C: the objective charges nothing for overshoot below 3 C, a user still sees it. Where a
change holds worse than the reference, its line names what the worse hold buys. Where nothing beats the
reference, the closest candidate that never trips and is not the reference's own parameters is an option,
with its trade (``Verdict.trade``).
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
MIN_GAIN_REL = 0.05
SAME_REL = 1e-6  # a candidate this close to the reference's parameters is the reference (a search that found it)
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
    trade: str = ""  # keep: what the closest candidate that never trips would change (gain_line); "" none
    closest: str | None = None  # keep: the candidate closest to beating the reference, not the reference's gains

    @property
    def keep(self) -> bool:
        return self.kind == KEEP

    @property
    def shown(self) -> str | None:
        """The candidate to show beside the reference: the answer, else the one with the fewest misses, one
        that never trips before one that does."""
        if self.method is not None or self.closest is not None or not self.misses:
            return self.method or self.closest
        return min(self.misses, key=lambda m: (_trips(self.misses[m]), sum(len(v) for v in self.misses[m].values())))


def _trips(missed: dict[str, list[str]]) -> bool:
    return any(why.startswith("trips") for reasons in missed.values() for why in reasons)


def judge(rows: list[ProofRow], reference: str, order: Sequence[str], ensemble: Ensemble | None) -> Verdict:
    """Of the candidates of ``order`` that beat the reference (the method named ``reference``) on every
    member and on the ensemble's cost, the best safe one (``safest``), else keep your gains, with the closest
    candidate's trade."""
    by = {(r.method, r.member): r for r in rows}
    members = list(dict.fromkeys(r.member for r in rows))
    ref_rows = [by[(reference, m)] for m in members]
    ref_cost = ensemble_cost(ref_rows, ensemble)
    plants = ensemble.kind if ensemble else "plants"
    misses: dict[str, dict[str, list[str]]] = {}
    for method in order:
        rows_c = [by[(method, m)] for m in members]
        missed = {m: why for m, c, r in zip(members, rows_c, ref_rows) if (why := member_misses(c, r))}
        cost = ensemble_cost(rows_c, ensemble)
        if not missed and cost > (1.0 - MIN_GAIN_REL) * ref_cost:
            missed = {"ensemble": [f"objective {cost:.4g} s, not {MIN_GAIN_REL:.0%} below the reference's "
                                   f"{ref_cost:.4g} s"]}
        misses[method] = missed
    passing = [m for m in order if not misses[m]]
    if passing:
        method = safest({m: [by[(m, member)] for member in members] for m in passing})
        rows_c = [by[(method, m)] for m in members]
        return Verdict(NEW, method, gain_line(rows_c, ref_rows, plants, ensemble), misses)
    other = {m: v for m, v in misses.items() if not np.allclose(by[(m, members[0])].params, ref_rows[0].params,
                                                                 rtol=SAME_REL, atol=0.0)} or misses
    closest = Verdict(KEEP, None, "", other).shown
    trade = "" if closest is None or _trips(misses[closest]) else \
        gain_line([by[(closest, m)] for m in members], ref_rows, plants, ensemble)
    return Verdict(KEEP, None, keep_line(other, plants), misses, trade, closest)


def _worst(rows: Sequence[ProofRow], attr: str) -> float:
    return max(getattr(r, attr)[1] for r in rows)


def safest(passing: dict[str, list[ProofRow]]) -> str:
    """Of the candidates that beat the reference (the search's cheapest first), the first, unless another
    holds as well (worst hold within HOLD_FACTOR and HOLD_SLACK_C of the first's) and overshoots less by more
    than OVERSHOOT_SLACK_C: then the one of them that overshoots least."""
    first = next(iter(passing))
    hold_bound = _worst(passing[first], "hold_error_c") * HOLD_FACTOR + HOLD_SLACK_C
    alike = [m for m, rows in passing.items() if _worst(rows, "hold_error_c") <= hold_bound]
    least = min(alike, key=lambda m: _worst(passing[m], "overshoot_c"))
    if _worst(passing[least], "overshoot_c") < _worst(passing[first], "overshoot_c") - OVERSHOOT_SLACK_C:
        return least
    return first


def _change(name: str, ours: float, yours: float, unit: str, digits: int = 2) -> str:
    if abs(ours - yours) < 0.5 * 10 ** -digits:
        return f"{name} unchanged ({yours:.{digits}f}{unit})"
    return f"{name} {yours:.{digits}f} -> {ours:.{digits}f}{unit}"


def gain_line(candidate: Sequence[ProofRow], reference: Sequence[ProofRow], plants: str = "plants",
              ensemble: Ensemble | None = None) -> str:
    """What a user gets by changing, worst over members and seeds: overshoot, hold, chatter, trips; where the
    hold is worse, what that buys (the better terms, and the objective: heat-up time and all)."""
    def mean(rows: Sequence[ProofRow], attr: str) -> float:
        return float(np.mean([getattr(r, attr)[0] for r in rows]))

    overshoot_c, overshoot_r = _worst(candidate, "overshoot_c"), _worst(reference, "overshoot_c")
    hold_c, hold_r = _worst(candidate, "hold_error_c"), _worst(reference, "hold_error_c")
    parts = [_change("overshoot", overshoot_c, overshoot_r, " C", 1), _change("hold", hold_c, hold_r, " C")]
    better = [parts[0]] if overshoot_c < overshoot_r - 0.05 else []
    chatter_c, chatter_r = mean(candidate, "chatter"), mean(reference, "chatter")
    if chatter_r > 0:
        parts.append(f"duty chatter {100.0 * (chatter_c / chatter_r - 1.0):+.0f} %")
        better += [parts[-1]] if chatter_c < chatter_r else []
    trips = sum(r.trips for r in reference)
    if trips:
        parts.append(f"trips {trips} -> 0")
        better.append(parts[-1])
    where = f"all {len(candidate)} {plants}" if len(candidate) > 1 else f"the one {plants.replace('plants', 'plant', 1)}"
    line = f"{', '.join(parts)}, on {where} (worst seed)"
    if hold_c >= hold_r + 0.005:  # a worse hold, as printed: say what it buys
        cost_c, cost_r = ensemble_cost(candidate, ensemble), ensemble_cost(reference, ensemble)
        better.append(f"objective {cost_r:.4g} -> {cost_c:.4g} s (heat-up time, overshoot beyond 3 C, hold, chatter)")
        line += f"; the worse hold buys {', '.join(better)}"
    return line


def keep_line(misses: dict[str, dict[str, list[str]]], plants: str = "plants") -> str:
    """Why nothing beats the printer's gains, in one line: the closest candidate's misses."""
    if not misses:
        return "no candidate to try"
    method = Verdict(KEEP, None, "", misses).shown
    assert method is not None
    missed = misses[method]
    member, why = next(iter(missed.items()))
    more = f" (and on {len(missed) - 1} more)" if len(missed) > 1 else ""
    return (f"nothing beats them on all {plants}: the closest, {method}, misses on {member}: "
            f"{'; '.join(why)}{more}")
