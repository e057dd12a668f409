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
  computed from the model), the same parallel PID law (the incremental reading with span 0).

    from tools.seeds.seed001 import reproduce
    result = reproduce()
    result.stable_readings, result.responses

Where the paper cannot be right, ``reproduce`` says so with the evidence it computed: Table 1's
settling times are shorter than the dead time, before which the model's output has not moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import cast

import numpy as np
from scipy.optimize import brentq

from firmware_port.fuzzy_pid import (
    INCREMENTAL,
    LITERAL,
    SEED001,
    SEED001_BOARD,
    FuzzyPid,
    FuzzyPidConfig,
    FuzzyPidFloat,
    infer,
)
from firmware_port.marlin.pid import PidGains
from tools.ident.fopdt import Fopdt, ultimate_point
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


@dataclass(frozen=True)
class Response:
    """One controller's step response in one loop (None: not reached within the run)."""

    controller: str
    loop: str  # "ideal" (the paper's) or "twin"
    rise_time_s: float | None
    overshoot_pct: float | None
    settling_time_2pct_s: float | None
    steady_state_error_c: float
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
        "fuzzy-PID literal": (PAPER_SCALING, SEED001),
        "fuzzy-PID incremental": (zn, replace(SEED001, reading=INCREMENTAL, span=INCREMENTAL_SPAN)),
        "PID Ziegler-Nichols": (zn, replace(SEED001, reading=INCREMENTAL, span=0.0)),
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


def reproduce() -> Seed001Result:
    """Both loops, three controllers; which readings are stable; what Table 1 cannot be."""
    ku, pu = ultimate_point(PLANT)
    zn = ziegler_nichols(PLANT)
    responses, first_moves = [], []
    for name, (gains, config) in _controllers(zn).items():
        ideal, first_move_s = ideal_response(name, gains, config)
        responses += [ideal, twin_response(name, gains, config)]
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


__all__ = ["Response", "Seed001Result", "reproduce", "ultimate_integral_gain", "ziegler_nichols"]
