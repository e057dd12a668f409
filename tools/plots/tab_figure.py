"""The OctoPrint tab's figure, made for its width (WIDTH_PX): your gains against the answer on the nominal plant,
the temperature from just below the target (the approach, the overshoot, the hold) above the heater's duty.

twin-tune's full figure (tools/plots/tune_figure.py) is a click away in the tab; this one draws only the two curves
a user chooses between, with the same labels, styles and trip marks. The canonical call (tools/cli/tune_work.py,
``--plot-compact``)::

    write(path, result, proof, describe)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from tools.plots.marks import mark_trip, new_figure, trip_words
from tools.plots.tune_figure import Curve, curves
from tools.tuning.evaluate import Candidate
from tools.tuning.tuner import Proven, TuneResult

WIDTH_PX, HEIGHT_PX, DPI = 560, 400, 100  # the tab's column in OctoPrint's default layout
BELOW_TARGET_C = 15.0  # the temperature panel starts this far below the target: the heat-up's end, not its start
LABEL_FONT = 7


def chosen(result: TuneResult, proof: Proven | None, describe: Callable[[Candidate], str]) -> list[Curve]:
    """The answer (or, unproven, the search's best) and the gains to beat, as twin-tune's figure draws them."""
    return curves(result, proof, describe)[:2 if proof is None or proof.answer is not None else 1]


def draw(result: TuneResult, proof: Proven | None, describe: Callable[[Candidate], str]):
    """The figure (module docstring): temperature above, duty below, one legend under both."""
    drawn = chosen(result, proof, describe)
    fig, (temp_ax, duty_ax) = new_figure(2, WIDTH_PX / DPI, HEIGHT_PX / DPI, sharex=True,
                                         gridspec_kw={"height_ratios": [3, 1.4]})
    target_c = drawn[0].candidate.run.target_c
    for curve in drawn:
        _draw(temp_ax, duty_ax, curve)
    top = max(float(np.max(c.candidate.run.temp_c[:, 0])) for c in drawn)
    temp_ax.axhline(target_c, color="k", ls=":", lw=0.8)
    temp_ax.set_ylim(target_c - BELOW_TARGET_C, max(top, target_c) + 2.0)
    temp_ax.set_ylabel("temperature (C)", fontsize=LABEL_FONT + 1)
    duty_ax.set_ylabel("duty (%)", fontsize=LABEL_FONT + 1)
    duty_ax.set_ylim(-3, 103)
    duty_ax.set_xlabel("time (s) on the nominal plant: heat-up, then the disturbances", fontsize=LABEL_FONT + 1)
    for ax in (temp_ax, duty_ax):
        ax.tick_params(labelsize=LABEL_FONT)
        for event in result.problem.scenario.events:
            ax.axvline(event.at_s, color="grey", ls="--", lw=0.5)
    fig.legend(*temp_ax.get_legend_handles_labels(), loc="outside lower center", ncols=1, fontsize=LABEL_FONT)
    return fig


def _draw(temp_ax, duty_ax, curve: Curve) -> None:
    run = curve.candidate.run
    t_s, temp_c, duty = run.t_s, run.temp_c[:, 0], run.duty[:, 0]
    until = t_s <= curve.trip[0] if curve.trip is not None else slice(None)  # a halted board's trace says nothing
    style = {**curve.style, "lw": min(curve.style["lw"], 1.6)}
    temp_ax.plot(t_s[until], temp_c[until], label=curve.label, **style)
    duty_ax.plot(t_s[until], 100.0 * duty[until], **{**style, "lw": 0.8})
    if curve.trip is not None:
        at_s, reason = curve.trip
        mark_trip(temp_ax, t_s, temp_c, at_s, style["color"], trip_words(curve.candidate.method, reason, at_s))


def write(path: Path, result: TuneResult, proof: Proven | None, describe: Callable[[Candidate], str]) -> None:
    """Draw the figure and save it to ``path`` (its folder made)."""
    fig = draw(result, proof, describe)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
