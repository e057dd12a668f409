"""One result type for every engine: ``Twin``, ``BatchTwin`` (a lane axis) and ``KlipperTwin``.

A run gives time in seconds and, per heater, named arrays: the target, the temperature the
firmware measured, the true sensor-node and heater-block temperatures and the heater duty
(0..1). A batch's arrays have shape (rows, lanes); a single run's (rows,). Events are what the
firmware printed and what the scenario did, with their times. Exports (CSV, Klipper ``Stats``
lines) and plots read from here, as the canonical call shows::

    result = twin.run(600)
    result.hotend.measured_c, result.hotend.metrics().overshoot_c
    result.plot("run.png")
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from twin.metrics import StepMetrics, format_metrics_table, max_deviation_c, recovery_time_s, segments, step_metrics

HEATERS = ("hotend", "bed")
FIELDS = ("target_c", "measured_c", "block_c", "sensor_c", "duty")
KLIPPER_NAMES = {"hotend": "extruder", "bed": "heater_bed"}
HEATER_IDS = {"hotend": "E0", "bed": "bed"}  # the Heater_ID Marlin prints in its errors
TRIP_SUFFIX = ", system stopped! Heater_ID: "  # Marlin's _temp_error line


@dataclass(frozen=True)
class HeaterRun:
    """One heater's arrays over a run: shape (rows,) or (rows, lanes)."""

    name: str
    t_s: np.ndarray
    target_c: np.ndarray
    measured_c: np.ndarray  # what the firmware read (its ADC and table), degC
    block_c: np.ndarray  # true heater-block temperature
    sensor_c: np.ndarray  # true sensor-node temperature
    duty: np.ndarray  # heater duty 0..1 (soft-PWM amount / 127 on Marlin)
    signals: dict[str, np.ndarray] = field(default_factory=dict)  # what its controller published (e.g. PID's p, i, d)

    @property
    def lanes(self) -> int | None:
        return self.measured_c.shape[1] if self.measured_c.ndim == 2 else None

    def lane(self, index: int) -> HeaterRun:
        """One lane of a batch as a single run."""
        run = HeaterRun(self.name, self.t_s, *(getattr(self, f)[:, index] if getattr(self, f).ndim == 2
                                               else getattr(self, f) for f in FIELDS))
        return replace(run, signals={k: v[:, index] if v.ndim == 2 else v for k, v in self.signals.items()})

    def metrics(self, **options) -> StepMetrics | list[StepMetrics]:
        """Step metrics (twin.metrics.step_metrics) of the first segment with a non-zero target
        (else the first), on the firmware-measured temperature; one per lane for a batch.
        ``options`` go to step_metrics."""
        if self.lanes is not None:
            return [self.lane(k)._first_step(options) for k in range(self.lanes)]
        return self._first_step(options)

    def _first_step(self, options: dict) -> StepMetrics:
        options = dict(options)
        spans = segments(self.t_s, self.target_c)
        start_s, end_s = next((span for span in spans if self.target_c[self.t_s >= span[0]][0] != 0), spans[0])
        return step_metrics(self.t_s, self.measured_c, self.target_c, self.duty,
                            start_s=options.pop("start_s", start_s), end_s=options.pop("end_s", end_s), **options)

    def steps(self) -> list[StepMetrics]:
        """Metrics of every segment with a constant, non-zero target (single runs)."""
        t_s, target = self.t_s, self.target_c
        return [step_metrics(t_s, self.measured_c, target, self.duty, start_s=start, end_s=end)
                for start, end in segments(t_s, target)
                if target[t_s >= start][0] > 0 and t_s[(t_s >= start) & (t_s < end)].size > 2]


@dataclass(frozen=True)
class RunResult:
    """Time, per-heater arrays, the part fan and the events of one run (or a batch of lanes)."""

    t_s: np.ndarray
    heaters: dict[str, HeaterRun]
    fan: np.ndarray
    events: list[tuple[float, str]] = field(default_factory=list)  # (t_s, text)
    label: str = ""  # what ran: firmware, plants, gains (plot titles)

    @classmethod
    def from_columns(cls, t_s, columns: dict[str, dict[str, np.ndarray]], fan=None,
                     events: Sequence[tuple[float, str]] = (), label: str = "") -> RunResult:
        """Build from {heater: {field: array}}; missing fields are NaN; ``signals`` (a heater's optional
        {name: array}) are its controller's published internals."""
        t_s = np.asarray(t_s, dtype=float)
        heaters = {}
        for name, cols in columns.items():
            shape = np.shape(cols["measured_c"])
            signals = {k: np.asarray(v, dtype=float) for k, v in dict(cols.get("signals", {})).items()}
            arrays: list[Any] = [np.asarray(cols[f], dtype=float) if f in cols else np.full(shape, np.nan) for f in FIELDS]
            heaters[name] = replace(HeaterRun(name, t_s, *arrays), signals=signals)
        fan = np.zeros(len(t_s)) if fan is None else np.asarray(fan, dtype=float)
        return cls(t_s, heaters, fan, list(events), label)

    def __getattr__(self, name: str) -> HeaterRun:
        heaters = self.__dict__.get("heaters", {})
        if name in heaters:
            return heaters[name]
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r} (heaters: {', '.join(heaters)})")

    def protection_trips(self) -> list[tuple[float, str, str]]:
        """(time, what, heater id) of each thermal protection error Marlin printed."""
        found = []
        for t_s, text in self.events:
            if text.startswith("Error:") and TRIP_SUFFIX in text:
                what, heater_id = text[len("Error:"):].split(TRIP_SUFFIX)
                found.append((t_s, what, heater_id))
        return found

    def report(self, disturbances: Sequence[tuple[float, str]] = ()) -> str:
        """Step metrics per setpoint of each heater, a line for each step whose hold limit-cycles, then the
        hotend's recovery after each disturbance (time, description)."""
        out = []
        for name, heater in self.heaters.items():
            steps = heater.steps()
            if steps:
                out += [f"{name} (firmware-measured temperature):", format_metrics_table(steps)]
            out += [f"{name} step {k}: limit cycle in the hold, +-{m.limit_cycle_amplitude_c:.2f} C every "
                    f"{m.limit_cycle_period_s:.1f} s: it never settles (no steady_state_error_c)"
                    for k, m in enumerate(steps, 1) if m.limit_cycle_amplitude_c is not None]
            if name != "hotend":
                continue
            for at_s, what in disturbances:
                if at_s >= self.t_s[-1]:
                    continue
                after = self.t_s >= at_s
                rec = recovery_time_s(self.t_s, heater.measured_c, heater.target_c, at_s)
                dev = max_deviation_c(self.t_s[after], heater.measured_c[after], heater.target_c[after], at_s)
                rec_text = f"{rec:.1f} s" if rec is not None else "not recovered"
                out.append(f"{name} after {what} at {at_s:g} s: max deviation {dev:.2f} C, recovery to +-2 C {rec_text}")
        return "\n".join(out) if out else "no heater had a target"

    # -- exports ---------------------------------------------------------------------------------
    def columns(self) -> list[tuple[str, np.ndarray]]:
        """(name, array) in the CSV's order: t_s, per heater its fields, fan."""
        cols = [("t_s", self.t_s)]
        for name in HEATERS:
            if name in self.heaters:
                cols += [(f"{name}_{f}", getattr(self.heaters[name], f)) for f in FIELDS]
        return cols + [("fan", self.fan)]

    def to_csv(self) -> str:
        """All rows, then one commented line per event (``# event <t_s> <text>``); single runs."""
        if any(h.lanes is not None for h in self.heaters.values()):
            raise ValueError("a batch result has a lane axis: export one lane (result.lane(k))")
        names, arrays = zip(*self.columns())
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(names)
        for row in zip(*arrays):
            writer.writerow(f"{v:.4f}" for v in row)
        for t_s, text in self.events:
            out.write(f"# event {t_s:.3f} {text}\n")
        return out.getvalue()

    def to_klipper_stats(self) -> str:
        """One ``Stats`` line per second, as klippy.log writes them (graphstats.py reads these).

        temp is the last reading, pwm the duty in force, target rounded to an integer.
        """
        lines = []
        next_s = 1.0
        for i, t_s in enumerate(self.t_s):
            if t_s < next_s:
                continue
            parts = [f"Stats {t_s:.1f}:"]
            for name, heater in self.heaters.items():
                parts.append(f"{KLIPPER_NAMES[name]}: target={heater.target_c[i]:.0f} "
                             f"temp={heater.measured_c[i]:.1f} pwm={heater.duty[i]:.3f}")
            parts.append(f"print_time={t_s:.3f} buffer_time=0.000 print_stall=0")
            lines.append(" ".join(parts))
            next_s = np.floor(t_s) + 1.0
        return "\n".join(lines) + ("\n" if lines else "")

    def lane(self, index: int) -> RunResult:
        """One lane of a batch result as a single-run result."""
        return RunResult(self.t_s, {n: h.lane(index) for n, h in self.heaters.items()}, self.fan, self.events,
                         f"{self.label} lane {index}".strip())

    def plot(self, path: str | None = None, title: str | None = None):
        """Temperature, target and duty over time per heater, protection trips marked; a batch draws
        every lane (matplotlib, the ``plot`` extra: ImportError with an install hint without it).
        Saved as PNG when ``path`` is given; returns the figure."""
        try:
            import matplotlib

            if path is not None:
                matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError as exc:
            raise ImportError("plots need matplotlib: pip install 'heater-twin[plot]'") from exc

        names = list(self.heaters)
        fig, axes = plt.subplots(len(names), 1, figsize=(10, 3.6 * len(names)), sharex=True, squeeze=False)
        for ax, name in zip(axes[:, 0], names):
            _plot_heater(ax, self.heaters[name], self.protection_trips())
        axes[-1, 0].set_xlabel("time (s)")
        fig.suptitle(title if title is not None else self.label)
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=110)
            plt.close(fig)
        return fig


def _plot_heater(ax, heater: HeaterRun, tripped: list[tuple[float, str, str]]) -> None:
    """One heater's panel: measured (every lane of a batch), true block, target, duty on the right axis, trips."""
    t_s, batch = heater.t_s, heater.lanes is not None
    ax.plot(t_s, heater.measured_c, label=None if batch else "measured (firmware)", lw=0.8 if batch else 1.2,
            color="tab:blue", alpha=0.5 if batch else 1.0)
    if not batch:
        ax.plot(t_s, heater.block_c, label="block (true)", lw=0.8, alpha=0.7, color="tab:orange")
    target = heater.target_c[:, 0] if batch else heater.target_c
    ax.step(t_s, target, where="post", label="target", color="k", lw=0.8, ls="--")
    ax.set_ylabel(f"{heater.name} temperature (°C)")
    duty_ax = ax.twinx()
    duty_line = duty_ax.plot(t_s, heater.duty, color="tab:red", lw=0.5, alpha=0.35 if batch else 0.5)
    duty_ax.set_ylim(0, 1.05)
    duty_ax.set_ylabel("duty (0..1)")
    for t, what, heater_id in tripped:
        own = heater_id == HEATER_IDS.get(heater.name)
        ax.axvline(t, color="red", lw=1.5 if own else 0.8, alpha=1.0 if own else 0.4)
        if own:
            ax.annotate(f"{what} ", (t, ax.get_ylim()[1]), fontsize=8, color="red", rotation=90, va="top", ha="right")
    handles, labels = ax.get_legend_handles_labels()
    if batch:
        handles, labels = [ax.lines[0], *handles], [f"measured, {heater.lanes} lanes", *labels]
    ax.legend([*handles, duty_line[0]], [*labels, "duty (right axis)"], loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
