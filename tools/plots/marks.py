"""What twin-tune's and twin-compare's figures mark the same way: a protection trip where it happened, and tick
labels as plain numbers (no ``9.14x10^1``)."""

from __future__ import annotations

from typing import Any

import numpy as np

TRIP_MARKER = "X"
TRIP_SIZE = 11


def new_figure(rows: int, width_in: float, height_in: float, **options: Any):
    """A figure of ``rows`` stacked axes laid out by matplotlib's constrained layout (room for a legend outside),
    drawn without pyplot: no backend to choose, nothing global to close."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    return fig, fig.subplots(rows, 1, squeeze=False, **options)[:, 0]


def trip_words(name: str, reason: str, at_s: float) -> str:
    """A trip's legend entry: who tripped, the firmware's words, when."""
    return f"{name} trips: {reason} at {at_s:.0f} s"


def mark_trip(ax, t_s: np.ndarray, temp_c: np.ndarray, at_s: float, color, label: str | None) -> None:
    """A cross on the trace where the protection tripped (its temperature then), labelled for the legend."""
    ax.plot([at_s], [float(np.interp(at_s, t_s, temp_c))], ls="none", marker=TRIP_MARKER, ms=TRIP_SIZE, color=color,
            mec="red", mew=1.5, zorder=6, label=label)


def plain_ticks(axis) -> None:
    """An axis's major tick labels as plain numbers, its minor ticks unlabelled (a log scale's default labels
    them as ``9.14x10^1``)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_formatter(NullFormatter())
