"""Plots of a twin trace (matplotlib is the optional ``plot`` extra)."""

from __future__ import annotations

from twin.trace import Trace

HEATER_IDS = {"hotend": "E0", "bed": "bed"}


def plot_trace(trace: Trace, path: str, title: str, heaters: tuple[str, ...] = ("hotend", "bed")) -> None:
    """Temperature, target and duty over time per heater, protection trips marked; saved as PNG.

    Raises ImportError with an install hint when matplotlib is missing.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError("plots need matplotlib: pip install 'heater-twin[plot]'") from exc

    t_s = trace.column("t_s")
    fig, axes = plt.subplots(len(heaters), 1, figsize=(10, 3.6 * len(heaters)), sharex=True, squeeze=False)
    tripped = trace.protection_trips()
    for ax, heater in zip(axes[:, 0], heaters):
        ax.plot(t_s, trace.column(f"{heater}_measured_c"), label="measured (firmware)", lw=1.2)
        ax.plot(t_s, trace.column(f"{heater}_block_c"), label="block (true)", lw=0.8, alpha=0.7)
        ax.step(t_s, trace.column(f"{heater}_target_c"), where="post", label="target", color="k", lw=0.8, ls="--")
        ax.set_ylabel(f"{heater} temperature (C)")
        duty_ax = ax.twinx()
        duty_ax.plot(t_s, trace.column(f"{heater}_duty"), color="tab:red", lw=0.5, alpha=0.5, label="duty")
        duty_ax.set_ylim(0, 1.05)
        duty_ax.set_ylabel("duty (0..1)")
        for t, what, heater_id in tripped:
            own = heater_id == HEATER_IDS[heater]
            ax.axvline(t, color="red", lw=1.5 if own else 0.8, alpha=1.0 if own else 0.4)
            if own:
                ax.annotate(f"{what} ", (t, ax.get_ylim()[1]), fontsize=8, color="red", rotation=90,
                            va="top", ha="right")
        ax.legend(loc="lower right", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
