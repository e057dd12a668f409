"""twin-tune's figure: the answer and your gains first, then the other candidates, on the nominal plant.

The top panel is the whole run (heat-up, then the disturbances, labelled), the next the hold zoomed; every
drawn candidate that tripped thermal protection ends in a cross where it tripped (a halted board's trace says
nothing after) and has a legend entry naming the trip, every one whose heat-up hold limit-cycles a bar of the cycle's amplitude; ``history`` adds a panel of
each optimiser's best cost per iteration. The canonical call (tools/cli/tune_work.py)::

    write(path, result, proof, title_words("hotend", "capture.txt", result, proof), describe, history=False)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.plots.marks import mark_trip, new_figure, plain_ticks, trip_words
from tools.tuning.answer import reference_name
from tools.tuning.evaluate import Candidate, first_run_trips
from tools.tuning.objectives import Run
from tools.tuning.tuner import YOURS, Proven, TuneResult
from twin.metrics import LimitCycle, limit_cycle

OTHERS = 4  # the search's best candidates drawn besides the answer and the references
ANSWER_STYLE = {"color": "tab:blue", "lw": 2.2, "zorder": 4}
YOURS_STYLE = {"color": "black", "lw": 1.6, "zorder": 3}
OTHER_COLORS = ("tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray", "tab:red",
                "tab:orange")
ZOOM_LEAD_S = 20.0  # the zoomed hold starts this long (or a limit cycle's period and a half) before the first event
DPI = 110


@dataclass(frozen=True)
class Curve:
    """One candidate as drawn: its legend label and line style, its trip (time, words) and its hold's limit cycle."""

    candidate: Candidate
    label: str
    style: dict
    trip: tuple[float, str] | None = None
    cycle: LimitCycle | None = None


def title_words(heater: str, source: str, result: TuneResult, proof: Proven | None) -> str:
    """The title in a user's words: the heater, the capture (or preset) and the verdict with its hold error."""
    if proof is None:
        return f"{heater}, {source}: unproven (--proof 0), the best of the search"
    if proof.verdict.keep or proof.answer is None:
        return f"{heater}, {source}: keep {reference_name(result.problem, proof.yours.method)}"
    what = "gains" if result.problem.controller.pid else "parameters"
    yours, answer = (max(r.hold_error_c[1] for r in proof.rows if r.method == c.method)
                     for c in (proof.yours, proof.answer))
    return f"{heater}, {source}: new {what}, hold {yours:.2f} -> {answer:.2f} C (worst plant and seed)"


def curves(result: TuneResult, proof: Proven | None, describe: Callable[[Candidate], str]) -> list[Curve]:
    """What the figure draws, in order: the answer (or, unproven, the best of the search), the gains to beat,
    the search's best few and the other references, then every other candidate that tripped on the nominal
    plant; with their trips and limit cycles."""
    answer = result.best if proof is None else proof.answer
    yours = result.yours
    head = "the best of the search (unproven)" if proof is None else "answer"
    chosen: list[tuple[Candidate, str, dict]] = []
    if answer is not None:
        chosen.append((answer, f"{head}: {describe(answer)}", ANSWER_STYLE))
    named = "your gains" if yours.method == YOURS else f"to beat, {yours.method}"
    chosen.append((yours, f"{named}: {describe(yours)}", YOURS_STYLE))
    others = result.candidates[:OTHERS] + result.references
    others += [c for c in result.candidates[OTHERS:] if _tripped(c.run)]
    for c in others:
        if all(c is not drawn for drawn, _, _ in chosen):
            color = OTHER_COLORS[(len(chosen) - 2) % len(OTHER_COLORS)]
            chosen.append((c, f"{c.method}: {describe(c)}", {"color": color, "lw": 0.9, "zorder": 2, "alpha": 0.85}))
    tripped = [c for c, _, _ in chosen if _tripped(c.run)]
    trips = dict(zip(map(id, tripped), first_run_trips(result.problem, np.array([c.params for c in tripped]))
                     if tripped else []))
    if missed := [c.method for c in tripped if trips[id(c)] is None]:
        raise RuntimeError(f"the scalar twin did not trip where the batch did: {', '.join(missed)} (a bug)")
    return [Curve(c, label, style, trips.get(id(c)), None if _tripped(c.run) else hold_cycle(c.run))
            for c, label, style in chosen]


def _tripped(run: Run) -> bool:
    """Whether the nominal plant's run (lane 0) tripped."""
    return bool(np.ravel(run.tripped)[0])


def hold_cycle(run: Run) -> LimitCycle | None:
    """The limit cycle of the nominal plant's heat-up hold (twin/metrics.py), as twin-tune's metrics report it."""
    heat = run.t_s < run.heatup_end_s
    return limit_cycle(run.t_s[heat], run.temp_c[heat, 0], run.target_c)


def draw(result: TuneResult, proof: Proven | None, title: str, describe: Callable[[Candidate], str],
         history: bool = False):
    """The figure (module docstring); ``describe`` words a candidate's parameters as twin-tune prints them."""
    drawn = curves(result, proof, describe)
    searched = [c for c in result.candidates if c.history is not None] if history else []
    fig, axes = new_figure(2 + bool(searched), 11, 8 + 3 * bool(searched))
    run0 = drawn[0].candidate.run
    for ax in axes[:2]:
        for curve in drawn:
            _draw_curve(ax, curve, labelled=ax is axes[0])
        _draw_scenario(ax, result, run0)
    axes[0].set_title("the whole run on the nominal plant: heat-up, then the disturbances", fontsize=10)
    _zoom(axes[1], drawn, run0)
    if searched:
        _draw_history(axes[2], searched)
    fig.suptitle(title, fontsize=12)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=8)
    return fig


def _draw_curve(ax, curve: Curve, labelled: bool) -> None:
    run = curve.candidate.run
    t_s, temp_c = run.t_s, run.temp_c[:, 0]
    until = t_s <= curve.trip[0] if curve.trip is not None else slice(None)  # a halted board's trace says nothing
    ax.plot(t_s[until], temp_c[until], label=curve.label if labelled else None, **curve.style)
    color = curve.style["color"]
    if curve.trip is not None:
        at_s, reason = curve.trip
        mark_trip(ax, t_s, temp_c, at_s, color, trip_words(curve.candidate.method, reason, at_s) if labelled else None)
    if curve.cycle is not None:
        cycle = curve.cycle
        end_s = run.heatup_end_s if run.heatup_end_s <= t_s[-1] else float(t_s[-1])
        last = (t_s >= end_s - cycle.period_s) & (t_s <= end_s)
        label = f"{curve.candidate.method}: limit cycle +-{cycle.amplitude_c:.2f} C every {cycle.period_s:.1f} s"
        ax.errorbar([end_s - cycle.period_s / 2], [float(np.mean(temp_c[last]))], yerr=[cycle.amplitude_c],
                    color=color, capsize=6, elinewidth=2, capthick=2, fmt="none", zorder=5,
                    label=label if labelled else None)


def _draw_scenario(ax, result: TuneResult, run0: Run) -> None:
    """The target and each disturbance, named."""
    ax.axhline(run0.target_c, color="k", ls=":", lw=0.8)
    for event in result.problem.scenario.events:
        ax.axvline(event.at_s, color="grey", ls="--", lw=0.6)
        ax.annotate(f"{event.kind} {event.value:g}", (event.at_s, 1.0), xycoords=("data", "axes fraction"),
                    xytext=(2, -10), textcoords="offset points", fontsize=8, color="grey")
    ax.set(xlabel="time (s)", ylabel="temperature the firmware reads (C)")


def _zoom(ax, drawn: list[Curve], run0: Run) -> None:
    """The hold, from just before the first disturbance on, scaled to the curves that did not trip."""
    lead_s = max([ZOOM_LEAD_S] + [1.5 * c.cycle.period_s for c in drawn if c.cycle is not None])
    start_s = max(float(run0.t_s[0]), run0.heatup_end_s - lead_s)
    hold = run0.t_s >= start_s
    kept = [c for c in drawn if c.trip is None] or drawn
    deviation = max(float(np.max(np.abs(c.candidate.run.temp_c[hold, 0] - run0.target_c))) for c in kept)
    ax.set(xlim=(start_s, float(run0.t_s[-1])),
           ylim=(run0.target_c - 1.1 * deviation, run0.target_c + 1.1 * deviation))
    ax.set_title("holding, from just before the first disturbance on (zoomed)", fontsize=10)


def _draw_history(ax, searched: list[Candidate]) -> None:
    """Each optimiser's best cost per iteration, plain tick labels."""
    from matplotlib.ticker import MaxNLocator

    for c in searched:
        ax.plot(np.asarray(c.history), marker=".", label=f"{c.method}: best cost so far")
    costs = np.concatenate([np.asarray(c.history, float) for c in searched])
    if costs.min() > 0 and costs.max() / costs.min() > 10:
        ax.set_yscale("log")
    plain_ticks(ax.yaxis)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set(xlabel="optimiser iteration", ylabel="best cost (the objective)", title="the search's progress")
    ax.legend(loc="upper right", fontsize=8)


def write(path: Path, result: TuneResult, proof: Proven | None, title: str, describe: Callable[[Candidate], str],
          history: bool = False) -> None:
    """Draw the figure and save it to ``path`` (its folder made)."""
    fig = draw(result, proof, title, describe, history)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
