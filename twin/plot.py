"""Plots of a run result (matplotlib is the optional ``plot`` extra)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from twin.result import HEATER_IDS

if TYPE_CHECKING:
    from twin.result import RunResult


def plot_result(result: RunResult, path: str | None = None, title: str | None = None):
    """Temperature, target and duty over time per heater, protection trips marked; a batch draws
    every lane. Saved as PNG when ``path`` is given. ImportError with an install hint when
    matplotlib is missing."""
    try:
        import matplotlib

        if path is not None:
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError("plots need matplotlib: pip install 'heater-twin[plot]'") from exc

    t_s = result.t_s
    names = list(result.heaters)
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 3.6 * len(names)), sharex=True, squeeze=False)
    tripped = result.protection_trips()
    for ax, name in zip(axes[:, 0], names):
        heater = result.heaters[name]
        batch = heater.lanes is not None
        ax.plot(t_s, heater.measured_c, label=None if batch else "measured (firmware)", lw=0.8 if batch else 1.2,
                color="tab:blue", alpha=0.5 if batch else 1.0)
        if not batch:
            ax.plot(t_s, heater.block_c, label="block (true)", lw=0.8, alpha=0.7, color="tab:orange")
        target = heater.target_c[:, 0] if batch else heater.target_c
        ax.step(t_s, target, where="post", label="target", color="k", lw=0.8, ls="--")
        ax.set_ylabel(f"{name} temperature (°C)")
        duty_ax = ax.twinx()
        duty_line = duty_ax.plot(t_s, heater.duty, color="tab:red", lw=0.5, alpha=0.35 if batch else 0.5)
        duty_ax.set_ylim(0, 1.05)
        duty_ax.set_ylabel("duty (0..1)")
        for t, what, heater_id in tripped:
            own = heater_id == HEATER_IDS.get(name)
            ax.axvline(t, color="red", lw=1.5 if own else 0.8, alpha=1.0 if own else 0.4)
            if own:
                ax.annotate(f"{what} ", (t, ax.get_ylim()[1]), fontsize=8, color="red", rotation=90,
                            va="top", ha="right")
        handles, labels = ax.get_legend_handles_labels()
        if batch:
            handles, labels = [ax.lines[0], *handles], [f"measured, {heater.lanes} lanes", *labels]
        ax.legend([*handles, duty_line[0]], [*labels, "duty (right axis)"], loc="lower right", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(title if title is not None else result.label)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
