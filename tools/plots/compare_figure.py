"""twin-compare's figure: per check, the logged temperature against the twin's (and the heater power where the log
has it), titled in a user's words; where the twin shut down, a cross on its trace and a legend entry naming why,
as twin-tune's figure marks a trip (tools/plots/marks.py). The canonical call (tools/cli/compare.py)::

    write(path, [Trace("extruder: the twin replays ...", t_s, logged_c, twin_c)], "klippy.log: the log against the twin")
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.plots.marks import mark_trip, new_figure, trip_words

PANEL_HEIGHT_IN = 3.4
DPI = 100


@dataclass(frozen=True)
class Trace:
    """One panel: logged and twin temperatures on one clock (s), the heater power (0..1) where known, and the
    twin's shutdown (time on that clock, its words) where it shut down."""

    title: str
    t_s: np.ndarray
    logged_c: np.ndarray
    twin_c: np.ndarray
    log_power: np.ndarray | None = None
    twin_power: np.ndarray | None = None
    trip: tuple[float, str] | None = None


def draw(traces: list[Trace], title: str):
    """The figure: one panel per trace, its legend at an explicit place, the title on top."""
    fig, axes = new_figure(len(traces), 10, 0.6 + PANEL_HEIGHT_IN * len(traces))
    for ax, trace in zip(axes, traces):
        _panel(ax, trace)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=11)
    return fig


def _panel(ax, trace: Trace) -> None:
    ax.plot(trace.t_s, trace.logged_c, label="logged temperature", lw=1.2, color="tab:blue")
    ax.plot(trace.t_s, trace.twin_c, label="the twin's temperature", lw=1.0, color="tab:orange")
    if trace.trip is not None:
        at_s, reason = trace.trip
        mark_trip(ax, trace.t_s, trace.twin_c, at_s, "tab:orange", trip_words("the twin", reason, at_s))
    ax.set_title(trace.title, fontsize=9)
    ax.set_ylabel("temperature (C)")
    handles, labels = ax.get_legend_handles_labels()
    top = ax
    if trace.log_power is not None:
        top = ax.twinx()
        top.step(trace.t_s, trace.log_power, where="post", color="tab:green", lw=0.6, label="logged heater power")
        if trace.twin_power is not None:
            top.step(trace.t_s, trace.twin_power, where="post", color="tab:red", lw=0.6, label="the twin's heater power")
        top.set_ylim(0, 1.05)
        top.set_ylabel("heater power (0..1)")
        more, more_labels = top.get_legend_handles_labels()
        handles, labels = handles + more, labels + more_labels
    top.legend(handles, labels, loc="lower right", fontsize=8, framealpha=0.9)  # on the top axes: not overdrawn


def write(path: Path, traces: list[Trace], title: str) -> None:
    """Draw the figure and save it to ``path`` (its folder exists: the CLI checked it)."""
    draw(traces, title).savefig(path, dpi=DPI)
