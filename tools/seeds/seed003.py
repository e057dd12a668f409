"""Seed 003 (PID tuning by the maximal stability degree method with iteration, MSDI, for third-order
models with a zero and time delay, applied to a 3D printer's extruder): its printed model and
table 1 beside our rerun. ``python -m tools.seeds.seed003`` prints the comparison.

What we rerun: the method of its section on materials and methods (tools/tuning/msdi.py) on its
identified model, eq. (9); each of its table-1 gain sets and ours on the idealised loop (a
continuous PID on the model, a unit set-point step, as its figure 4) and on the firmware twin
(the integer Marlin PID on the ``seed003_third`` preset, heating 25 -> 210 C). Where a printed
number cannot be right, ``evidence`` says why, from these computations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.optimize

from tools.tuning.gains import Gains
from tools.tuning.ideal import LoopRun, step_response
from tools.tuning.models import LinearModel, model_of
from tools.tuning.msdi import MsdiResult, Quasi, characteristic, gains_at, msdi, roots_right_of, terms
from tools.tuning.ultimate import UltimatePoint, relay_experiment, ultimate_point
from twin.engine import BOOT_S, Twin
from twin.metrics import StepMetrics, step_metrics
from twin.plants import SPECS, TransferFunction, make_plant

PRESET = "seed003_third"
# Seed 003 eq. (9), factored form: 0.72653 (163.40925 s + 1) e^-5s / ((634.10445 s + 1)(61.55245 s + 1)(0.50895 s + 1))
GAIN, LEAD_S, LAGS_S, DELAY_S = 0.72653, 163.40925, (634.10445, 61.55245, 0.50895), 5.0
# ... and its expanded form as printed: (118.7254 s + 0.72) e^-5s / (19864.64 s^3 + 39384.75 s^2 + 696.16 s + 1)
PRINTED_NUM = (118.7254, 0.72)
PRINTED_DEN = (19864.64, 39384.75, 696.16, 1.0)
_SPEC = SPECS[PRESET]
assert isinstance(_SPEC, TransferFunction)
INPUT_FULL_SCALE = _SPEC.input_full_scale  # the preset's assumed paper units at duty 1 (docs/plants.md)
DURATION_S = 1200.0  # idealised and firmware runs: long past the slowest closed-loop root's 160 s
TARGET_C, AMBIENT_C = 210.0, 25.0
TAIL_S = 300.0  # the last seconds of a firmware run, where a limit cycle's swing is measured


class PaperRow(NamedTuple):
    """Seed 003 table 1: tuning, J, gains (its model's input units per degC), rise time, overshoot,
    settling time (+-5 %) and number of deviations (None where the table's cell is empty)."""

    method: str
    j: float | None
    kp: float
    ki: float
    kd: float
    rise_s: float
    overshoot_pct: float
    settling_s: float
    deviations: int | None


PAPER_TABLE = (
    PaperRow("MSDI fig. 4a", 0.36, 96.13, 10.848, 2.16, 82.0, 5.5, 103.0, 1),
    PaperRow("MSDI fig. 4b", 0.78, 189.15, 35.02, 95.42, 82.0, 5.0, 102.0, None),
    PaperRow("MSDI fig. 4c", 1.24, 134.2, 4.6, 70.47, 74.0, 4.5, 82.0, None),
    PaperRow("ZN fig. 4d", None, 336.6, 34.22, 841.5, 80.0, 4.0, 92.0, 0),
)
MSDI_ROWS = tuple(row for row in PAPER_TABLE if row.j is not None)


class LoopCheck(NamedTuple):
    """One gain set (paper units) on the model: right-half-plane roots of the characteristic
    quasi-polynomial, the idealised step (its metrics unless it diverged) and the firmware twin's."""

    label: str
    gains: tuple[float, float, float]
    unstable_roots: int
    ideal: LoopRun
    ideal_metrics: StepMetrics | None
    twin_metrics: StepMetrics
    twin_tail_swing_c: float  # peak-to-peak of the firmware's reading over the run's last TAIL_S


@dataclass(frozen=True)
class Report:
    model: LinearModel  # eq. (9) in the paper's input units
    ours_expanded: tuple[np.ndarray, np.ndarray]
    ultimate: UltimatePoint
    relay: UltimatePoint
    msdi: MsdiResult
    slow_root: float
    ours_at_table_j: list[tuple[float, float, float]]
    checks: list[LoopCheck]
    evidence: list[str]

    def text(self) -> str:
        return format_report(self)


def paper_model() -> LinearModel:
    """Seed 003 eq. (9) in its own input units (the twin's preset is the same at input_full_scale 550)."""
    return model_of(TransferFunction(gain=GAIN, input_full_scale=1.0, lead_s=LEAD_S, lag1_s=LAGS_S[0],
                                     lag2_s=LAGS_S[1], lag3_s=LAGS_S[2], delay_s=DELAY_S))


def twin_step(gains: tuple[float, float, float]) -> tuple[StepMetrics, float]:
    """The Marlin integer PID on the preset with these paper-unit gains (duty = input / 550),
    heating 25 -> 210 C: the step's metrics and the last TAIL_S seconds' swing."""
    tw = Twin([make_plant(PRESET, ambient_c=AMBIENT_C)], "pid")
    tw.boot(BOOT_S)
    tw.hotend.gains = Gains.from_duty(*(g / INPUT_FULL_SCALE for g in gains)).firmware()
    tw.hotend.target_c = TARGET_C
    run = tw.run(DURATION_S).hotend
    tail = run.measured_c[run.t_s >= DURATION_S - TAIL_S]
    metrics = run.metrics()
    assert isinstance(metrics, StepMetrics)  # a single twin: one step
    return metrics, float(np.ptp(tail))


def check(label: str, model: LinearModel, quasi: Quasi, gains: tuple[float, float, float]) -> LoopCheck:
    ideal = step_response(model, gains, duration_s=DURATION_S)
    metrics = None if ideal.diverged else step_metrics(ideal.t_s, ideal.output, 1.0)
    return LoopCheck(label, gains, roots_right_of(quasi, gains, 0.0), ideal, metrics, *twin_step(gains))


def _slow_root(quasi: Quasi, gains: tuple[float, float, float]) -> float:
    """The real closed-loop root next to the model's zero (-1/LEAD_S), by bisection on D."""
    zero = -1.0 / LEAD_S
    return float(scipy.optimize.brentq(lambda s: characteristic(quasi, gains, s).real, 1.05 * zero, 0.95 * zero))


def _residual(quasi: Quasi, gains: tuple[float, float, float], j: float) -> float:
    """|D(-J)| over the sum of its parts' magnitudes: 0 when -J is a root, order 1 when far from one."""
    parts = terms(quasi, gains, -j, 1)[0]
    return float(abs(parts.sum()) / np.abs(parts).sum())


def _evidence(up: UltimatePoint, checks: list[LoopCheck], quasi: Quasi,
              ours_at_j: list[tuple[float, float, float]]) -> list[str]:
    """Where table 1 cannot be right, in sentences, from the computations."""
    lines = []
    for row, chk in zip(PAPER_TABLE, checks[: len(PAPER_TABLE)], strict=True):
        if chk.unstable_roots:
            lines.append(
                f"{row.method}: Kp {row.kp:g} Ki {row.ki:g} Kd {row.kd:g} leave {chk.unstable_roots} roots of the "
                f"characteristic quasi-polynomial in the right half plane (argument principle); the idealised loop "
                f"diverges (|y| > 1e6 at {chk.ideal.t_s[-1]:.0f} s), yet the table reports settling in "
                f"{row.settling_s:g} s with {row.overshoot_pct:g} % overshoot")
        if row.j is not None:
            residual = _residual(quasi, (row.kp, row.ki, row.kd), row.j)
            lines.append(f"{row.method}: at J = {row.j:g} D(-J) with the table's gains is {residual:.2f} of its "
                         "parts' size: -J is not a root, so these gains do not come from eqs. (5)-(8) at that J")
    for row, ours in zip(MSDI_ROWS, ours_at_j, strict=True):
        if min(ours) < 0:
            lines.append(f"J = {row.j:g}: eqs. (5)-(8) give Kp {ours[0]:.3g} Ki {ours[1]:.3g} Kd {ours[2]:.3g}, all "
                         "negative: past the maximal stability degree the method has no positive gains")
    zn = PAPER_TABLE[3]
    lines.append(f"ZN row: Kp = 0.6 Ku gives Ku = {zn.kp / 0.6:.1f}, Tu = 8 Kd/Kp = {8 * zn.kd / zn.kp:.1f} s "
                 f"(2 Kp/Ki = {2 * zn.kp / zn.ki:.1f} s); eq. (9)'s own ultimate point is Ku = {up.ku:.1f}, "
                 f"Tu = {up.tu_s:.1f} s: the period agrees, the gain is {zn.kp / 0.6 / up.ku:.1f} times the model's "
                 "(the ZN gains do not fit this model; an input unit 5.8 times smaller would make them consistent)")
    above = [row.method for row in PAPER_TABLE if row.kp > up.ku]
    lines.append(f"Kp above the model's ultimate gain {up.ku:.1f}: {', '.join(above)}")
    return lines


def reproduce() -> Report:
    """Seed 003's model, its MSDI gains and table 1 beside ours (see the module docstring)."""
    model = paper_model()
    quasi = Quasi.third_order_zero(GAIN, LEAD_S, LAGS_S, DELAY_S)
    up = ultimate_point(model)
    relay = relay_experiment(model).point
    result = msdi(quasi)
    ours_at_j = [gains_at(quasi, row.j) for row in MSDI_ROWS if row.j is not None]
    checks = [check(row.method, model, quasi, (row.kp, row.ki, row.kd)) for row in PAPER_TABLE]
    checks.append(check(f"ours MSDI J = {result.j:.4f}", model, quasi, result.gains))
    return Report(model, (quasi.num, quasi.den), up, relay, result, _slow_root(quasi, result.gains), ours_at_j,
                  checks, _evidence(up, checks, quasi, ours_at_j))


def _cell(value: float | None, fmt: str = ".1f") -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, fmt)


def format_report(report: Report) -> str:
    num, den = report.ours_expanded
    kp, ki, kd = report.msdi.gains
    lines = [
        "Seed 003 reproduction (MSDI PID tuning, third-order model with a zero and delay)",
        f"model eq. (9) expanded, printed: ({PRINTED_NUM[0]} s + {PRINTED_NUM[1]}) / ({PRINTED_DEN[0]} s^3 + "
        f"{PRINTED_DEN[1]} s^2 + {PRINTED_DEN[2]} s + {PRINTED_DEN[3]:g})",
        f"  ours from the factored form: ({num[0]:.4f} s + {num[1]:.5f}) / ({den[0]:.2f} s^3 + {den[1]:.2f} s^2 + "
        f"{den[2]:.3f} s + {den[3]:g})",
        f"ultimate point (model): Ku {report.ultimate.ku:.2f} Tu {report.ultimate.tu_s:.2f} s; "
        f"ideal relay: Ku {report.relay.ku:.2f} Tu {report.relay.tu_s:.2f} s",
        f"our MSDI: J = {report.msdi.j:.4f} (first maximum of kp(J), common to ki and kd), Kp {kp:.3f} Ki {ki:.4f} "
        f"Kd {kd:.3f}; roots right of -J: {report.msdi.roots_right} (real root at {report.slow_root:.5f} 1/s, "
        f"next to the zero -1/{LEAD_S:g} = {-1 / LEAD_S:.5f})",
        "  on the twin (duty = input / 550): " + str(Gains.from_duty(*(g / INPUT_FULL_SCALE for g in report.msdi.gains))),
        "eqs. (5)-(8) at the table's J (ours):",
    ]
    for row, ours in zip(MSDI_ROWS, report.ours_at_table_j, strict=True):
        lines.append(f"  J {row.j:<5g} printed Kp {row.kp:<7g} Ki {row.ki:<7g} Kd {row.kd:<7g}  ours Kp {ours[0]:<8.3f} "
                     f"Ki {ours[1]:<8.4f} Kd {ours[2]:.3f}")
    lines.append("step responses: printed (rise, overshoot %, settling 5 %) | idealised loop, unit step "
                 "(RHP roots; rise, overshoot %, settling 5 %) | firmware twin 25->210 C (overshoot C, "
                 f"settling 2 %, swing over the last {TAIL_S:g} s)")
    for i, chk in enumerate(report.checks):
        printed = PAPER_TABLE[i] if i < len(PAPER_TABLE) else None
        head = (f"{printed.rise_s:g} s, {printed.overshoot_pct:g} %, {printed.settling_s:g} s" if printed else "-")
        m = chk.ideal_metrics
        ideal = (f"diverges by {chk.ideal.t_s[-1]:.0f} s" if m is None else
                 f"{_cell(m.rise_time_s)} s, {_cell(m.overshoot_pct)} %, {_cell(m.settling_time_5pct_s)} s")
        t = chk.twin_metrics
        lines.append(f"  {chk.label:<22} printed {head:<22} | ideal ({chk.unstable_roots}) {ideal:<26} | twin "
                     f"{_cell(t.overshoot_c)} C, {_cell(t.settling_time_2pct_s)} s, swing {chk.twin_tail_swing_c:.2f} C")
    lines.append("evidence:")
    lines += [f"  - {line}" for line in report.evidence]
    return "\n".join(lines)


def main() -> None:
    print(reproduce().text())


if __name__ == "__main__":
    main()
