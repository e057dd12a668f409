"""Seed 001 (Fuzzy-PID nozzle temperature control, 2022): its experiment, re-run.

The paper steps its FOPDT nozzle model (eq. 9, 0.196 e^(-20.7 s) / (24 s + 1)) from 0 to 180 C
under the fuzzy-PID of section 3 and a PID, in Simulink, and prints Table 1 (settling time,
overshoot, steady-state error). Here:

- the paper-compatible loop (``tools.tuning.ideal.closed_loop``: unbounded controller output, unity
  feedback) and the firmware twin (the ``seed001_fopdt`` preset behind the 10-bit ADC, the
  thermistor table and the 7-bit soft PWM of a saturating heater; integer controllers);
- the fuzzy-PID in both readings of its tables (``firmware_port.fuzzy_pid``): literal, with the
  paper's output scaling factors 1 as base gains, and incremental, correcting Ziegler-Nichols gains;
- the comparison PID: Ziegler-Nichols' closed-loop rule on the same plant (ultimate gain and period
  computed from the model), the same parallel PID law (the incremental reading with span 0);
- the literal reading at a scale that fits the plant: the paper's scaling factors 1 put ki at
  the setpoint 5.4 times above the plant's ultimate integral gain (unstable in either loop), so
  the literal reading is also run with scaling factors ZN / 1.5: its gains at the setpoint (the
  centroid of ZO, 1.5) are Ziegler-Nichols', and its tables move them between 0 and 2 times those.

    from tools.seeds.seed001 import reproduce
    result = reproduce()
    result.stable_readings, result.responses

Where the paper cannot be right, ``reproduce`` says so with the evidence it computed: Table 1's
settling times are shorter than the dead time, before which the model's output has not moved.
"""

from __future__ import annotations

import sys

import math
from dataclasses import dataclass, replace
from typing import cast

import numpy as np
from scipy.optimize import brentq

from firmware_port.fuzzy_pid import (
    INCREMENTAL,
    LITERAL,
    OUT_ZO,
    SEED001,
    SEED001_BOARD,
    FuzzyPid,
    FuzzyPidConfig,
    FuzzyPidFloat,
    infer,
)
from firmware_port.firmwares import build_controllers
from firmware_port.marlin.pid import PidGains
from tools.ident.fopdt import Fopdt, ultimate_point
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
from tools.tuning.ideal import closed_loop
from tools.tuning.models import model_of
from twin.engine import BOOT_S, Twin
from twin.metrics import step_metrics
from twin.plants import SPECS, TransferFunction, make_plant

PRESET = "seed001_fopdt"
_SPEC = cast(TransferFunction, SPECS[PRESET])
PLANT = Fopdt(_SPEC.gain, _SPEC.lag1_s, _SPEC.delay_s)  # eq. (9)
IDEAL_MODEL = model_of(replace(_SPEC, input_full_scale=1.0))  # eq. (9) per unit of the controller's output
STEP_C = 180.0  # section 3: "喷头起始温度为 0℃, 目标温度为 180℃"
# Table 1 as printed: settling time (s), overshoot (%), steady-state error (units not stated).
PAPER_TABLE1 = {
    "PID": {"settling_time_s": 0.49, "overshoot_pct": 2.69, "steady_state_error": 0.31},
    "Fuzzy-PID": {"settling_time_s": 0.31, "overshoot_pct": 0.14, "steady_state_error": 0.24},
}
PAPER_SCALING = PidGains(1.0, 1.0, 1.0)  # "比例因子 kp、ki 和 kd 均取 1": the literal reading's base gains

IDEAL_DT_S = 0.1  # divides the 20.7 s dead time; the paper's solver step is not stated
DURATION_S = 1000.0  # ~15 ultimate periods: long enough to see a loop settle or grow
INCREMENTAL_SPAN = 0.5  # NB/PB move a gain by -/+50 % (a choice: the paper gives no base gains)
# The twin's Marlin board halts below HEATER_0_MINTEMP (5 C), so the paper's 0 C start is
# impossible there; the plant is linear in the rise above ambient, so 20 -> 200 C is the same step.
TWIN_AMBIENT_C = 20.0
COUNTS_PER_INPUT = 255 / _SPEC.input_full_scale  # the board's 0..255 spans the preset's input
LITERAL_NAME, FITTED_LITERAL_NAME = "fuzzy-PID literal", "fuzzy-PID literal, scaling ZN / 1.5"
INCREMENTAL_NAME, PID_NAME = "fuzzy-PID incremental", "PID Ziegler-Nichols"


@dataclass(frozen=True)
class Response:
    """One controller's step response in one loop (None: not reached within the run)."""

    controller: str
    loop: str  # "ideal" (the paper's) or "twin"
    rise_time_s: float | None
    overshoot_pct: float | None
    settling_time_2pct_s: float | None
    steady_state_error_c: float | None  # None: it limit-cycles (twin/metrics.py)
    peak_c: float  # the largest rise above the start, degC
    stable: bool  # settled into the 2 % band and stayed, with the firmware running
    note: str  # why not, if not


@dataclass(frozen=True)
class Seed001Result:
    zn_gains: PidGains  # paper units: plant input per degC
    ultimate_gain: float
    ultimate_period_s: float
    responses: tuple[Response, ...]
    paper: dict[str, dict[str, float]]
    dead_time_s: float
    first_move_s: float  # when the ideal loop's output first leaves 0
    stable_readings: tuple[str, ...]  # the readings whose ideal and twin loops both settle
    literal_ki_at_setpoint: float  # the literal reading's ki at e = ec = 0 (rules ZO, ZO), 1/s
    ultimate_integral_gain: float  # the plant's limit for integral action alone, 1/s
    impossible: tuple[str, ...]  # the paper's numbers that cannot be right, with the evidence


def ultimate_integral_gain(plant: Fopdt) -> float:
    """The largest ki of a pure integral controller ki/s that keeps the loop stable: phase
    crossover of ``ki K e^(-L s) / (s (T s + 1))`` at ``atan(w T) + w L = pi / 2``."""
    w = brentq(lambda w: math.atan(w * plant.time_constant_s) + w * plant.delay_s - math.pi / 2, 1e-9,
               math.pi / (2 * plant.delay_s))
    return w * math.hypot(1.0, w * plant.time_constant_s) / plant.gain_c


def ziegler_nichols(plant: Fopdt) -> PidGains:
    """Ziegler and Nichols (1942) closed-loop rule: Kp = 0.6 Ku, Ti = Pu / 2, Td = Pu / 8."""
    ku, pu = ultimate_point(plant)
    kp = 0.6 * ku
    return PidGains(kp, kp / (pu / 2), kp * pu / 8)


def _controllers(zn: PidGains) -> dict[str, tuple[PidGains, FuzzyPidConfig]]:
    """Name -> (base gains in paper units, configuration)."""
    return {
        LITERAL_NAME: (PAPER_SCALING, SEED001),
        FITTED_LITERAL_NAME: (PidGains(zn.kp / OUT_ZO, zn.ki / OUT_ZO, zn.kd / OUT_ZO), SEED001),
        INCREMENTAL_NAME: (zn, replace(SEED001, reading=INCREMENTAL, span=INCREMENTAL_SPAN)),
        PID_NAME: (zn, replace(SEED001, reading=INCREMENTAL, span=0.0)),
    }


def _growth(t_s, rise_c) -> float:
    """Largest |error| over the last quarter of the run over that of the second quarter."""
    e = abs(np.asarray(rise_c) - STEP_C)
    quarter = (np.asarray(t_s) - t_s[0]) / (t_s[-1] - t_s[0]) * 4
    return float(e[quarter >= 3].max() / e[(quarter >= 1) & (quarter < 2)].max())


def _response(name: str, loop: str, t_s, rise_c, halted_note: str) -> Response:
    m = step_metrics(t_s, rise_c, STEP_C)
    settled = m.settling_time_2pct_s is not None and not halted_note
    note = halted_note
    if not (settled or note):
        note = f"never settles in the 2 % band; the error's envelope grows x{_growth(t_s, rise_c):.3g} per quarter run"
    return Response(name, loop, m.rise_time_s, m.overshoot_pct, m.settling_time_2pct_s, m.steady_state_error_c,
                    float(max(rise_c)), settled, note)


def ideal_response(name: str, gains: PidGains, config: FuzzyPidConfig) -> tuple[Response, float]:
    """The paper's loop; also returns when its output first moves."""
    ctl = FuzzyPidFloat(gains, config, dt_s=IDEAL_DT_S, out_max=None)
    run = closed_loop(IDEAL_MODEL, ctl.step, STEP_C, DURATION_S, IDEAL_DT_S)
    first_move_s = float(run.t_s[next(i for i, y in enumerate(run.output) if y > 0)])
    return _response(name, "ideal", run.t_s, run.output, ""), first_move_s


def twin_response(name: str, gains: PidGains, config: FuzzyPidConfig) -> Response:
    """The firmware twin: the integer fuzzy-PID, gains scaled to the board's 0..255 output."""
    scaled = PidGains(gains.kp * COUNTS_PER_INPUT, gains.ki * COUNTS_PER_INPUT, gains.kd * COUNTS_PER_INPUT)
    board_config = replace(config, ke=SEED001_BOARD.ke)  # 0.4 rounded to Q12, as the board holds it
    twin = Twin([make_plant(PRESET, ambient_c=TWIN_AMBIENT_C)], "fuzzy_pid",
                controllers=[FuzzyPid(scaled, board_config)])
    twin.boot(BOOT_S)
    twin.hotend.target_c = TWIN_AMBIENT_C + STEP_C
    run = twin.run(DURATION_S).hotend
    halted = ""
    if twin.board.halted:
        t_s, text = next((t, line) for t, line in twin.trace.events if line.startswith("Error:"))
        halted = f"the firmware halted at {t_s:.1f} s: {text}"
    return _response(name, "twin", run.t_s, run.measured_c - TWIN_AMBIENT_C, halted)


def reproduce(progress: Progress = no_progress) -> Seed001Result:
    """Both loops, four controllers; which readings are stable; what Table 1 cannot be."""
    ku, pu = ultimate_point(PLANT)
    zn = ziegler_nichols(PLANT)
    responses, first_moves = [], []
    for name, (gains, config) in _controllers(zn).items():
        ideal, first_move_s = ideal_response(name, gains, config)
        progress(f"{name}, paper loop")
        responses += [ideal, twin_response(name, gains, config)]
        progress(f"{name}, firmware twin")
        first_moves.append(first_move_s)
    stable = tuple(reading for reading in (LITERAL, INCREMENTAL)
                   if all(r.stable for r in responses if r.controller == f"fuzzy-PID {reading}"))
    first_move_s = min(first_moves)
    impossible = [
        f"Table 1 {name}: settling time {row['settling_time_s']} s, but the model's output does not "
        f"move before {first_move_s:.1f} s (dead time {PLANT.delay_s} s)"
        for name, row in PAPER_TABLE1.items() if row["settling_time_s"] < first_move_s
    ]
    ki_setpoint = infer(0.0, 0.0)[1] * PAPER_SCALING.ki
    ki_u = ultimate_integral_gain(PLANT)
    if LITERAL not in stable and ki_setpoint > ki_u:
        impossible.append(
            f"Table 1 Fuzzy-PID with scaling factors 1 read literally: ki = {ki_setpoint:g} /s at the setpoint, "
            f"{ki_setpoint / ki_u:.1f} x the plant's ultimate integral gain {ki_u:.3f} /s; the loop is unstable")
    return Seed001Result(zn, ku, pu, tuple(responses), PAPER_TABLE1, PLANT.delay_s, first_move_s, stable,
                         ki_setpoint, ki_u, tuple(impossible))




# -- the command's and the page's report ----------------------------------------------------------

LOOPS = (
    f"paper loop: eq. (9) with the controller's output unbounded (Simulink's loop, the paper states no limit), "
    f"step {IDEAL_DT_S} s, 0 -> {STEP_C:.0f} C; no firmware and no firmware delay",
    f"firmware twin: the `{PRESET}` preset (eq. 9 behind the 10-bit ADC and the thermistor table, a heater that "
    f"saturates at {_SPEC.input_full_scale:.0f} input units), the integer controllers on the board every 0.164 s, "
    f"7-bit soft PWM, {TWIN_AMBIENT_C:.0f} -> {TWIN_AMBIENT_C + STEP_C:.0f} C: the firmware's loop with its delays",
)
DEFAULT_BUILD_S = 600.0  # twin-sim's heat_hold scenario: 600 s to 210 C
DEFAULT_BUILD_TARGET_C = 210.0


def steps(budget: Budget) -> int:
    """Progress calls of ``report``: 4 controllers x 2 loops, and the default build's run."""
    return 2 * 4 + 1


@dataclass(frozen=True)
class DefaultBuild:
    """``twin-sim --firmware fuzzy_pid --plant seed001_fopdt``: the build's own base gains on this plant."""

    gains: PidGains  # the build's base gains (M301 units: counts of 0..255)
    ultimate_gain_counts: float  # the plant's ultimate gain on the board's scale, counts/C
    halted_at_s: float | None
    message: str
    zn_counts: PidGains  # the gains to use instead
    zn_settling_s: float | None


def counts(gains: PidGains) -> PidGains:
    """Paper-unit gains (input per C) on the board's 0..255 scale (M301 units)."""
    return PidGains(gains.kp * COUNTS_PER_INPUT, gains.ki * COUNTS_PER_INPUT, gains.kd * COUNTS_PER_INPUT)


def _heat(controller: FuzzyPid | None) -> tuple[Twin, float | None]:
    """The heat_hold heat-up on the fuzzy_pid build (its own controller unless one is given)."""
    twin = Twin([make_plant(PRESET, ambient_c=25.0)], "fuzzy_pid", controllers=[controller] if controller else ())
    twin.boot(BOOT_S)
    twin.hotend.target_c = DEFAULT_BUILD_TARGET_C
    metrics = twin.run(DEFAULT_BUILD_S).hotend.metrics()
    assert not isinstance(metrics, list)  # one twin, one step
    return twin, metrics.settling_time_2pct_s


def default_build(result: Seed001Result) -> DefaultBuild:
    """Why the fuzzy_pid build halts on this plant with its defaults, and the gains that run."""
    twin, _ = _heat(None)
    halted_at_s, message = None, "ran to the end"
    if twin.board.halted:
        halted_at_s, message = next((t, line) for t, line in twin.trace.events if line.startswith("Error:"))
    zn = counts(result.zn_gains)
    _, settling_s = _heat(FuzzyPid(zn, SEED001_BOARD))
    build_gains = build_controllers("fuzzy_pid")[0].gains  # what twin-sim's fuzzy_pid runs
    return DefaultBuild(build_gains, result.ultimate_gain * COUNTS_PER_INPUT, halted_at_s, message, zn,
                        settling_s)


def _by(result: Seed001Result, controller: str, loop: str = "ideal") -> Response:
    return next(r for r in result.responses if r.controller == controller and r.loop == loop)


def _claims(result: Seed001Result) -> list[Verdict]:
    """Table 1's comparison (the fuzzy-PID beats the PID), judged in the stable reading."""
    fuzzy, pid = _by(result, INCREMENTAL_NAME), _by(result, PID_NAME)
    fitted = _by(result, FITTED_LITERAL_NAME)
    paper_f, paper_p = PAPER_TABLE1["Fuzzy-PID"], PAPER_TABLE1["PID"]
    rows = []
    for key, label, unit, decimals in (("settling_time_s", "settles faster than the PID", "s", 1),
                                       ("overshoot_pct", "overshoots less than the PID", "%", 2)):
        ours_key = "settling_time_2pct_s" if key == "settling_time_s" else key
        f, p = getattr(fuzzy, ours_key), getattr(pid, ours_key)
        holds = f < p
        also = getattr(fitted, ours_key)
        why = (f"in the stable (incremental) reading against Ziegler-Nichols' PID, paper loop; the literal reading "
               f"at scaling ZN / 1.5 gives {num(also, decimals)} {unit}")
        if not holds:
            why = f"the opposite of the paper's claim: {why}"
        rows.append(Verdict("table 1 and section 3", f"fuzzy-PID {label}",
                            f"{paper_f[key]:g} < {paper_p[key]:g} {unit}",
                            f"{num(f, decimals)} {'<' if holds else '>='} {num(p, decimals)} {unit}",
                            REPRODUCED if holds else DIFFERS, why, claim=True))
    return rows


def _overshoot_words(response: Response) -> str:
    overshoot = num(response.overshoot_pct)
    return "it diverges" if overshoot == "diverges" else f"overshoot {overshoot} %"


def verdicts(result: Seed001Result) -> list[Verdict]:
    rows = []
    zn = result.zn_gains
    literal = _by(result, LITERAL_NAME)
    for printed_name, ours_name in (("PID", PID_NAME), ("Fuzzy-PID", INCREMENTAL_NAME)):
        printed, ours = PAPER_TABLE1[printed_name], _by(result, ours_name)
        where = f"table 1, {printed_name}"
        source = (f"ours: Ziegler-Nichols on the model (Kp {num(zn.kp, 3)} Ki {num(zn.ki, 4)} Kd {num(zn.kd, 2)}; "
                  "the paper prints no PID gains)" if printed_name == "PID" else
                  "ours: the stable (incremental) reading on those gains; the literal reading with the paper's "
                  f"scaling factors 1 never settles ({_overshoot_words(literal)})")
        settle = printed["settling_time_s"]
        rows.append(Verdict(where, "settling time s", f"{settle:g}", num(ours.settling_time_2pct_s, 1),
                            IMPOSSIBLE if settle < result.first_move_s else DIFFERS,
                            f"the model's output does not move before {num(result.first_move_s, 1)} s (dead time "
                            f"{PLANT.delay_s} s); {source}"))
        overshoot = printed["overshoot_pct"]
        rows.append(Verdict(where, "overshoot %", f"{overshoot:g}", num(ours.overshoot_pct),
                            REPRODUCED if within(ours.overshoot_pct, overshoot, 0.005) else DIFFERS, source))
        error = printed["steady_state_error"]
        rows.append(Verdict(where, "steady-state error", f"{error:g}", num(ours.steady_state_error_c),
                            REPRODUCED if within(ours.steady_state_error_c, error, 0.005) else DIFFERS,
                            "with integral action the settled loop's error goes to 0 (ours: the last sample of "
                            f"{DURATION_S:.0f} s); the paper states neither the units nor the horizon"))
    return rows + _claims(result)


def _note_default(build: DefaultBuild) -> str:
    g, zn = build.gains, build.zn_counts
    ratio = g.kp / build.ultimate_gain_counts
    ran = (f"halts at {num(build.halted_at_s, 1)} s ({build.message})" if build.halted_at_s is not None
           else "runs to the end")
    fix = (f"twin-sim --firmware fuzzy_pid --plant {PRESET} --gains {zn.kp:.3f},{zn.ki:.4f},{zn.kd:.2f}` (Ziegler-"
           f"Nichols in counts; settles in {num(build.zn_settling_s, 1)} s)")
    return (f"`twin-sim --firmware fuzzy_pid --plant {PRESET}` {ran}: the build's base gains are Marlin's hotend "
            f"defaults (Kp {g.kp:g} Ki {g.ki:g} Kd {g.kd:g} counts), meant for the `hotend` preset; on this plant Kp "
            f"is {num(ratio, 1)} x its ultimate gain in counts ({num(build.ultimate_gain_counts, 3)} counts/C). "
            f"Run it with this plant's gains: `{fix}")


def report(budget: Budget = SMALL_BUDGET, progress: Progress = no_progress) -> SeedReport[Seed001Result]:
    """Seed 001 re-run: Table 1 beside ours, the claims, both loops' responses, the default build."""
    result = reproduce(progress)
    build = default_build(result)
    progress("the fuzzy_pid build's defaults")
    twin = Table(
        "Every controller in both loops (the twin's numbers have no printed counterpart):",
        ("controller", "loop", "rise s", "overshoot %", "settling 2 % s", "steady-state error C", "stable", "note"),
        tuple((r.controller, "paper" if r.loop == "ideal" else "firmware twin", num(r.rise_time_s, 1),
               num(r.overshoot_pct), num(r.settling_time_2pct_s, 1), num(r.steady_state_error_c),
               "yes" if r.stable else "no", r.note or "-") for r in result.responses))
    zn = result.zn_gains
    notes = (f"Ziegler-Nichols on the model: Ku {num(result.ultimate_gain, 4)}, Pu {num(result.ultimate_period_s, 2)} "
             f"s, Kp {num(zn.kp, 4)} Ki {num(zn.ki, 5)} Kd {num(zn.kd, 3)} (paper units: input per C)",
             *(line for line in result.impossible if "does not move before" not in line),  # those are verdicts
             _note_default(build))
    return SeedReport("001", "Fuzzy-PID nozzle temperature control", f"{budget}: no search (every budget runs the "
                      "same experiment)", LOOPS, tuple(verdicts(result)), result, (twin,), notes)


if __name__ == "__main__":  # python -m tools.seeds.seed001: the same as python -m tools.seeds 001
    from tools.seeds.command import main_for

    sys.exit(main_for("001", report, steps))
