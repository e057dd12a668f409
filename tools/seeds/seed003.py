"""Seed 003 (PID tuning by the maximal stability degree method with iteration, MSDI, for third-order
models with a zero and time delay, applied to a 3D printer's extruder): its printed model and
table 1 beside our rerun. ``python -m tools.seeds 003`` prints the comparison.

What we rerun: the method of its section on materials and methods (tools/tuning/msdi.py) on its
identified model, eq. (9); each of its table-1 gain sets and ours on the idealised loop (a
continuous PID on the model, a unit set-point step, as its figure 4) and on the firmware twin
(the integer Marlin PID on the ``seed003_third`` preset, heating 25 -> 210 C). Where a printed
number cannot be right, ``evidence`` says why, from these computations.
"""

from __future__ import annotations

import sys

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.optimize

from tools.seeds.report import (
    DIFFERS,
    IMPOSSIBLE,
    REPRODUCED,
    SMALL_BUDGET,
    Budget,
    Progress,
    SeedReport,
    Table,
    Verdict,
    no_progress,
    num,
    within,
)
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


def reproduce(progress: Progress = no_progress) -> Report:
    """Seed 003's model, its MSDI gains and table 1 beside ours (see the module docstring)."""
    model = paper_model()
    quasi = Quasi.third_order_zero(GAIN, LEAD_S, LAGS_S, DELAY_S)
    up = ultimate_point(model)
    relay = relay_experiment(model).point
    result = msdi(quasi)
    ours_at_j = [gains_at(quasi, row.j) for row in MSDI_ROWS if row.j is not None]
    progress("ultimate point, relay, MSDI")
    checks = []
    for label, gains in [*((row.method, (row.kp, row.ki, row.kd)) for row in PAPER_TABLE),
                         (f"ours MSDI J = {result.j:.4f}", result.gains)]:
        checks.append(check(label, model, quasi, gains))
        progress(label)
    return Report(model, (quasi.num, quasi.den), up, relay, result, _slow_root(quasi, result.gains), ours_at_j,
                  checks, _evidence(up, checks, quasi, ours_at_j))


# -- the command's and the page's report ----------------------------------------------------------

LOOPS = (
    "paper loop: eq. (9) under a continuous PID (unbounded output), a unit set-point step, as its figure 4; "
    "no firmware and no firmware delay",
    f"firmware twin: the `{PRESET}` preset (eq. 9, duty 1 = {INPUT_FULL_SCALE:g} input units), Marlin's integer PID "
    f"every 0.164 s, 10-bit ADC, 7-bit soft PWM, {AMBIENT_C:g} -> {TARGET_C:g} C: the firmware's loop with its delays",
)
MODEL_REL_TOL = 1e-3  # the printed expansion's coefficients carry 4-7 digits: agree to 0.1 %
PERIOD_REL_TOL = 0.10  # a period read off an oscillation: the model's relay experiment gives 21.38 s, the formula 21.47


def steps(budget: Budget) -> int:
    """Progress calls of ``report``: the model's computations, then 5 gain sets in both loops."""
    return 1 + len(PAPER_TABLE) + 1


def _model_verdicts(rep: Report) -> list[Verdict]:
    num_ours, den_ours = rep.ours_expanded
    rows = []
    for label, printed, ours in (("numerator", PRINTED_NUM, num_ours), ("denominator", PRINTED_DEN, den_ours)):
        for power, (p, o) in enumerate(zip(printed, ours, strict=True)):
            s_power = len(printed) - 1 - power
            rel = abs(float(o) / p - 1)
            agrees = rel <= MODEL_REL_TOL
            rows.append(Verdict("eq. (9), expanded", f"{label}, s^{s_power}", f"{p}", f"{float(o):.6g}",
                                REPRODUCED if agrees else DIFFERS,
                                f"the product of the factored form; {num(100 * rel, 4)} % apart (tolerance "
                                f"{100 * MODEL_REL_TOL:g} %)"))
    return rows


def _table_verdicts(rep: Report) -> list[Verdict]:
    rows = []
    for row, chk in zip(PAPER_TABLE, rep.checks[: len(PAPER_TABLE)], strict=True):
        m = chk.ideal_metrics
        for label, printed, name in (("rise s", row.rise_s, "rise_time_s"),
                                     ("overshoot %", row.overshoot_pct, "overshoot_pct"),
                                     ("settling 5 % s", row.settling_s, "settling_time_5pct_s")):
            if m is None:
                rows.append(Verdict(f"table 1, {row.method}", label, f"{printed:g}",
                                    f"diverges by {num(chk.ideal.t_s[-1], 0)} s", IMPOSSIBLE,
                                    f"Kp {row.kp:g} Ki {row.ki:g} Kd {row.kd:g} leave {chk.unstable_roots} roots of the "
                                    "characteristic quasi-polynomial in the right half plane: the loop diverges"))
            else:
                ours = getattr(m, name)
                agrees = within(ours, printed, 0.05 * abs(printed))
                rows.append(Verdict(f"table 1, {row.method}", label, f"{printed:g}", num(ours, 1),
                                    REPRODUCED if agrees else DIFFERS, "the printed gains in the paper's loop; +-5 %"))
    return rows


def _gain_verdicts(rep: Report, quasi: Quasi) -> list[Verdict]:
    rows = []
    for row, ours in zip(MSDI_ROWS, rep.ours_at_table_j, strict=True):
        assert row.j is not None  # MSDI rows carry their J
        residual = _residual(quasi, (row.kp, row.ki, row.kd), row.j)
        negative = min(ours) < 0
        why = (f"eqs. (5)-(8) at J = {row.j:g} give all-negative gains: past the maximal stability degree "
               f"(J = {num(rep.msdi.j, 4)}) the method has no positive gains" if negative else
               f"with the printed gains D(-J) is {num(residual)} of its parts' size: -J is not a root, so they do "
               "not come from eqs. (5)-(8) at that J")
        rows.append(Verdict(f"table 1, {row.method}", f"Kp / Ki / Kd at J = {row.j:g}",
                            f"{row.kp:g} / {row.ki:g} / {row.kd:g}",
                            f"{num(ours[0], 2)} / {num(ours[1], 3)} / {num(ours[2], 2)}", IMPOSSIBLE, why))
    zn, up = PAPER_TABLE[3], rep.ultimate
    ku = zn.kp / 0.6
    tu = 8 * zn.kd / zn.kp
    rows.append(Verdict("table 1, ZN fig. 4d", "ultimate gain Ku (Kp = 0.6 Ku)", num(ku, 1), num(up.ku, 1), DIFFERS,
                        f"the ZN gains are {num(ku / up.ku, 1)} x the model's ultimate gain: they do not fit eq. (9)"))
    agrees = within(up.tu_s, tu, PERIOD_REL_TOL * tu)
    rows.append(Verdict("table 1, ZN fig. 4d", "ultimate period Tu s (Td = Tu / 8)", num(tu, 1), num(up.tu_s, 2),
                        REPRODUCED if agrees else DIFFERS,
                        f"eq. (9)'s phase crossover; within {PERIOD_REL_TOL:.0%} (the ideal relay gives "
                        f"{num(rep.relay.tu_s, 2)} s)"))
    return rows


def verdicts(rep: Report) -> list[Verdict]:
    quasi = Quasi.third_order_zero(GAIN, LEAD_S, LAGS_S, DELAY_S)
    return _model_verdicts(rep) + _gain_verdicts(rep, quasi) + _table_verdicts(rep)


def report(budget: Budget = SMALL_BUDGET, progress: Progress = no_progress) -> SeedReport[Report]:
    """Seed 003 re-run: eq. (9), table 1's gains and responses beside ours, every gain set on the twin."""
    rep = reproduce(progress)
    kp, ki, kd = rep.msdi.gains
    checks = Table(
        "Every gain set (paper units) in both loops:",
        ("gains", "Kp / Ki / Kd", "RHP roots", "paper loop: rise s / overshoot % / settling 5 % s",
         f"twin: overshoot C / settling 2 % s / swing over the last {TAIL_S:g} s C"),
        tuple(_check_cells(chk) for chk in rep.checks))
    notes = (f"ours: eq. (9)'s ultimate point Ku {num(rep.ultimate.ku, 2)}, Tu {num(rep.ultimate.tu_s, 2)} s; our MSDI "
             f"at J = {num(rep.msdi.j, 4)} (the maximal stability degree): Kp {num(kp, 3)} Ki {num(ki, 4)} "
             f"Kd {num(kd, 3)}",
             "the twin differs from the paper's loop where the heater saturates (duty 0..1 against an unbounded input) "
             "and where the paper's loop diverges: the twin's bounded heater turns that into a limit cycle (the swing)",
             *(line for line in rep.evidence if line.startswith("Kp above")))
    return SeedReport("003", "PID tuning by the maximal stability degree method with iteration (MSDI)",
                      f"{budget}: no search (every budget runs the same experiment)", LOOPS, tuple(verdicts(rep)),
                      rep, (checks,), notes)


def _check_cells(chk: LoopCheck) -> tuple[str, ...]:
    m, t = chk.ideal_metrics, chk.twin_metrics
    kp, ki, kd = chk.gains
    ideal = (f"diverges by {num(chk.ideal.t_s[-1], 0)} s" if m is None else
             f"{num(m.rise_time_s, 1)} / {num(m.overshoot_pct, 1)} / {num(m.settling_time_5pct_s, 1)}")
    return (chk.label, f"{num(kp, 3)} / {num(ki, 4)} / {num(kd, 3)}", str(chk.unstable_roots), ideal,
            f"{num(t.overshoot_c, 1)} / {num(t.settling_time_2pct_s, 1)} / {num(chk.twin_tail_swing_c, 2)}")


if __name__ == "__main__":  # python -m tools.seeds.seed003: the same as python -m tools.seeds 003
    from tools.seeds.command import main_for

    sys.exit(main_for("003", report, steps))
