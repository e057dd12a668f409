"""Seed 002 (Zhou, Jiang, Du, Lu: "High-speed 3D printing temperature control with optimized PID
parameters based on improved ALO algorithm", preprint 2024): its printed numbers and our rerun.

Two experiments: the F1-F23 benchmark of its tables 2-4 (seed002_benchmark.py), and the PID tuning
of its section 4 on the identified hotend model, reproduced by ``reproduce()`` below; ``report()``
runs both and judges every printed number (``python -m tools.seeds 002``).

The PID experiment (seed 002, section 4), rebuilt as the paper describes it:
- plant: eq. 15, G(s) = 1.014 e^{-20 s} / (s^2 + 0.05 s + 0.001), simulated exactly between
  samples (zero-order hold) with the 20 s dead time as a sample delay; its input is taken as
  heater duty (its gain, 1014 C per unit, is a hotend's full-power rise), so the paper's printed
  platform gains (table 11, Klipper's 0..255 scale) can be tried on it after dividing by 255;
- controller: a continuous parallel PID Kp + Ki/s + Kd N s/(s + N) with N = 100, the default
  filter coefficient of Simulink's PID block (the paper builds its loop in Simulink), no output
  limits (the paper states none), run at SAMPLE_S; the setpoint is 0 before t = 0, so the
  derivative sees the step (as Simulink's step block does);
- objective: eq. 17, Q = integral of (w1 |e| + w2 u^2 + w3 |e| while overshooting) dt with
  w1 = 0.999, w2 = 0.001, w3 = 100, the extra term applying while the output is above the
  setpoint, over a step from 0 to 210 C (the paper's print temperature) for HORIZON_S;
- search: gains in [0, 100000]^3 (section 4.2), ALO and OCALO with the benchmark's population
  and iterations (the paper gives none for this experiment);
- reference: DE on the same Q in a box around the gains that matter for this plant (below),
  to show what Q the search range [0, 100000]^3 hides: with a plant gain of 1014 C per unit,
  useful Kp are about 1e-3, a 1e-8 sliver of the paper's range;
- disturbance (section 4.4): a 0.1 step added to the plant input at 520 s, recovery into the
  2 % band (Table 10) and the largest temperature after it.
"""

from __future__ import annotations

import sys

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import cont2discrete

from firmware_port.marlin.constants import HEATER_0_MAXTEMP_C, PID_FUNCTIONAL_RANGE_C
from tools.seeds import seed002_benchmark
from tools.seeds.report import (
    DIFFERS,
    IMPOSSIBLE,
    PAPER,
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
from tools.seeds.seed002_benchmark import ALGORITHMS
from tools.tuning.optim.benchmark import Results
from tools.tuning.gains import COUNTS_PER_DUTY, Gains
from tools.tuning.optim import METHODS
from tools.tuning.optim.result import OptimResult
from twin.engine import BOOT_S, Twin
from twin.klipper_twin import KlipperTwin, extruder_setup
from twin.metrics import StepMetrics, recovery_time_s, step_metrics
from twin.plants import make_plant

# -- the PID experiment (section 4) -------------------------------------------------------------
PLANT_NUM = 1.014  # seed 002 eq. 15 numerator
PLANT_DEN = (1.0, 0.05, 0.001)  # seed 002 eq. 15 denominator s^2 + 0.05 s + 0.001
DEAD_TIME_S = 20.0  # seed 002 eq. 15 ("the time delay is set to 20")
TABLE8 = {"k": 859.663, "omega": 0.034, "zeta": 0.737, "theta": 0.0}  # seed 002 table 8, as printed
FILTER_N = 100.0  # Simulink PID block's default derivative filter coefficient
W1, W2, W3 = 0.999, 0.001, 100.0  # seed 002 eqs. 16-17
GAIN_BOUNDS = [(0.0, 100000.0)] * 3  # seed 002 section 4.2: Kp, Ki, Kd in [0, 100000]
SETPOINT_C = 210.0  # seed 002's print temperature (table 7, tables 10-12)
HORIZON_S = 1000.0  # seed 002 figures 9-10 run to 1000 s
DISTURBANCE_AT_S, DISTURBANCE = 520.0, 0.1  # seed 002 section 4.4: "a 0.1 step signal at 520 s"
BAND = 0.02  # seed 002 section 4.4: recovery "within 2 % error bars"
# Our reference box: Kp up to a loop gain of about 10 (10 / 1014), integral time >= 10 s at that
# Kp, derivative time <= 100 s at that Kp; DE with scipy's defaults and this population.
REFERENCE_BOUNDS = [(0.0, 0.01), (0.0, 1e-3), (0.0, 1.0)]
REFERENCE_POPULATION = 30
SAMPLE_S = 0.1  # our fixed step: 1/300 of the plant's 200 s natural period, 1/200 of the dead time

# Printed results. Table 9 (simulation; "peak amplitude" read as overshoot in %, the only reading
# under which OCALO's 1.6 is "the smallest overshoot" of a 210 C step).
PRINTED_TABLE9 = {
    "OCALO": {"overshoot_pct": 1.59774, "peak_time_s": 321.4505, "rise_time_s": 272.0981, "settling_time_s": 351.3188},
    "ALO": {"overshoot_pct": 14.3121, "peak_time_s": 469.4281, "rise_time_s": 407.3485, "settling_time_s": 619.9532},
}
# Table 10 (after the 520 s disturbance): maximum temperature (C), recovery time (s; None: "-").
PRINTED_TABLE10 = {
    "OCALO": (219.3011, 225.1), "PSO": (312.3896, None), "ALO": (249.3161, None),
    "GALO": (230.1576, 247.5), "IALO": (244.86196, 244.2), "WALO": (218.2119, 242.9),
}  # fmt: skip
# Table 11 (physical platform, Klipper): overshoot %, peak s, stable s, Kp, Ki, Kd (0..255 scale).
PRINTED_TABLE11 = {
    "OCALO": (2.33, 61.0, 116.0, 20.837, 1.037, 104.708),
    "ALO": (2.86, 65.0, 352.0, 18.525, 0.912, 30.113),
}


def _plant_matrices(sample_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of eq. 15 without its dead time (state: y, dy/dt)."""
    a1, a0 = PLANT_DEN[1] / PLANT_DEN[0], PLANT_DEN[2] / PLANT_DEN[0]
    a = np.array([[0.0, 1.0], [-a0, -a1]])
    b = np.array([[0.0], [PLANT_NUM / PLANT_DEN[0]]])
    ad, bd, *_ = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), sample_s, method="zoh")
    return ad, bd[:, 0]


def simulate(
    gains: np.ndarray, *, sample_s: float = SAMPLE_S, horizon_s: float = HORIZON_S,
    disturbance_at_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Times, temperatures and controller outputs (lanes x samples) of the step to SETPOINT_C.

    gains: rows of (Kp, Ki, Kd) on the model's scale (duty per C). A lane that diverges carries
    inf/NaN from then on (its cost is inf).
    """
    gains = np.atleast_2d(np.asarray(gains, dtype=float))
    kp, ki, kd = gains.T
    delay = round(DEAD_TIME_S / sample_s)
    steps = round(horizon_s / sample_s)
    ad, bd = _plant_matrices(sample_s)
    lanes = gains.shape[0]
    x = np.zeros((2, lanes))
    integral, derivative, e_prev = np.zeros(lanes), np.zeros(lanes), np.zeros(lanes)
    temp, out = np.empty((lanes, steps)), np.zeros((lanes, steps + delay))
    disturb_from = steps if disturbance_at_s is None else round(disturbance_at_s / sample_s)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(steps):
            temp[:, k] = x[0]
            e = SETPOINT_C - x[0]
            integral += ki * e * sample_s
            derivative = (derivative + kd * FILTER_N * (e - e_prev)) / (1.0 + FILTER_N * sample_s)  # backward Euler
            e_prev = e
            out[:, k + delay] = kp * e + integral + derivative
            applied = out[:, k] + (DISTURBANCE if k >= disturb_from else 0.0)
            x = ad @ x + np.outer(bd, applied)
    return np.arange(steps) * sample_s, temp, out[:, delay:]


def q_cost(gains: np.ndarray, *, sample_s: float = SAMPLE_S, horizon_s: float = HORIZON_S) -> np.ndarray:
    """Seed 002's eq. 17 for each row of gains (model scale); inf where the simulation overflows."""
    _, temp, out = simulate(gains, sample_s=sample_s, horizon_s=horizon_s)
    error = SETPOINT_C - temp
    with np.errstate(over="ignore", invalid="ignore"):
        rate = W1 * np.abs(error) + W2 * out**2 + W3 * np.abs(error) * (error < 0)
        cost = np.sum(rate, axis=1) * sample_s
    return np.where(np.isfinite(cost), cost, np.inf)


@dataclass(frozen=True)
class LoopNumbers:
    """Step and disturbance figures of one set of gains on the eq. 15 loop."""

    gains: tuple[float, float, float]
    q: float
    overshoot_pct: float | None
    peak_time_s: float | None
    rise_time_s: float | None
    settling_time_s: float | None
    max_after_disturbance_c: float
    recovery_time_s: float | None
    min_control: float  # the controller's lowest output in the step run: below 0 asks the heater to cool


def loop_numbers(gains: tuple[float, float, float], sample_s: float = SAMPLE_S) -> LoopNumbers:
    """Seed 002's table 9 and 10 figures for one set of gains (model scale); None where the loop
    overflows before the end (the figures of an exploding response mean nothing)."""
    row = np.array([gains])
    t, temp, out = simulate(row, sample_s=sample_s)
    t_d, temp_d, _ = simulate(row, sample_s=sample_s, disturbance_at_s=DISTURBANCE_AT_S)
    q = float(q_cost(row, sample_s=sample_s)[0])
    if not (np.all(np.isfinite(temp)) and np.all(np.isfinite(temp_d))):
        return LoopNumbers(gains, q, None, None, None, None, float("inf"), None, float("-inf"))
    step = step_metrics(t, temp[0], SETPOINT_C)
    return LoopNumbers(
        gains=gains,
        q=q,
        overshoot_pct=step.overshoot_pct,
        peak_time_s=step.peak_time_s,
        rise_time_s=step.rise_time_s,
        settling_time_s=step.settling_time_2pct_s,
        max_after_disturbance_c=float(np.max(temp_d[0, t_d >= DISTURBANCE_AT_S])),
        recovery_time_s=recovery_time_s(t_d, temp_d[0], SETPOINT_C, DISTURBANCE_AT_S, BAND * SETPOINT_C),
        min_control=float(np.min(out[0])),
    )


def model_consistency() -> list[str]:
    """Evidence that table 8 and eq. 15 do not describe the same model."""
    a1, a0 = PLANT_DEN[1], PLANT_DEN[2]
    omega = np.sqrt(a0)
    zeta, gain = a1 / (2.0 * omega), PLANT_NUM / a0
    table = TABLE8
    return [
        f"eq. 15 has omega = sqrt({a0}) = {omega:.4f} rad/s, zeta = {a1}/(2 omega) = {zeta:.3f}, "
        f"k = {PLANT_NUM}/{a0} = {gain:.0f}; table 8 prints omega {table['omega']}, zeta {table['zeta']}, "
        f"k {table['k']} (k omega^2 = {table['k'] * table['omega'] ** 2:.4f}, not {PLANT_NUM})",
        f"table 8 prints delay theta = {table['theta']:g} s, eq. 15 uses {DEAD_TIME_S:g} s",
    ]


def printed_claims() -> list[str]:
    """Printed claims of section 4.4 that the paper's own table 10 contradicts."""
    smallest = min(PRINTED_TABLE10, key=lambda name: PRINTED_TABLE10[name][0])
    if smallest == "OCALO":
        return []
    return [
        f"section 4.4 says OCALO-PID has the smallest maximum peak after the disturbance, but table 10 "
        f"prints {smallest} {PRINTED_TABLE10[smallest][0]} C below OCALO's {PRINTED_TABLE10['OCALO'][0]} C"
    ]


@dataclass(frozen=True)
class Reproduction:
    """The paper's printed numbers beside ours, and the evidence against impossible ones."""

    ours: dict[str, LoopNumbers]
    runs: dict[str, OptimResult]
    printed_gains_on_model: dict[str, LoopNumbers]
    reference: LoopNumbers
    reference_run: OptimResult
    evidence: list[str] = field(default_factory=list)


def _triple(gains: np.ndarray) -> tuple[float, float, float]:
    kp, ki, kd = (float(g) for g in gains)
    return kp, ki, kd


def reproduce(
    *, seed: int = 0, population: int = 50, iterations: int = 300, sample_s: float = SAMPLE_S,
    reference_budget: int = 50 * REFERENCE_POPULATION, progress: Progress = no_progress,
) -> Reproduction:
    """Tune the eq. 15 loop with ALO and OCALO on Q (eq. 17) and measure tables 9-10's figures."""

    def objective(points: np.ndarray) -> np.ndarray:
        return q_cost(points, sample_s=sample_s)

    runs, ours = {}, {}
    for name in ("ALO", "OCALO"):
        rng = np.random.default_rng([seed, ALGORITHMS.index(name)])
        result = METHODS[name.lower()](
            objective, GAIN_BOUNDS, rng=rng, budget=population * iterations, population=population
        )
        runs[name] = result
        ours[name] = loop_numbers(_triple(result.x), sample_s)
        progress(f"section 4, {name} on Q")
    printed = {
        name: loop_numbers(_triple(np.array(row[3:]) / COUNTS_PER_DUTY), sample_s)
        for name, row in PRINTED_TABLE11.items()
    }
    reference = METHODS["de"](
        objective, REFERENCE_BOUNDS, rng=np.random.default_rng([seed, len(ALGORITHMS)]), budget=reference_budget,
        population=REFERENCE_POPULATION,
    )  # fmt: skip
    progress("section 4, the reference DE")
    return Reproduction(
        ours, runs, printed, loop_numbers(_triple(reference.x), sample_s), reference, model_consistency() + printed_claims()
    )


# -- on the firmware twin --------------------------------------------------------------------------

TWIN_PRESET = "seed002_sopdt"  # eq. 15 with its dead time, duty 0..1 = the model's input 0..1
TWIN_FROM_C = 25.0  # the twin's board halts below MINTEMP, so the step starts at a room's ambient


@dataclass(frozen=True)
class TwinRun:
    """One gain set (0..255 scale) on the firmware twin: the step's figures and how the firmware ended."""

    gains: Gains
    rise_time_s: float | None
    overshoot_c: float | None
    settling_time_2pct_s: float | None
    halted_at_s: float | None
    ended: str  # "ran to the end" or the firmware's error line
    t_s: np.ndarray
    reading_c: np.ndarray


def twin_run(gains: Gains) -> TwinRun:
    """The eq. 15 experiment on the firmware twin: Marlin's integer PID, TWIN_FROM_C -> SETPOINT_C."""
    twin = Twin([make_plant(TWIN_PRESET, ambient_c=TWIN_FROM_C)], "pid")
    twin.boot(BOOT_S)
    twin.hotend.gains = gains.firmware()
    twin.hotend.target_c = SETPOINT_C
    run = twin.run(HORIZON_S).hotend
    m = run.metrics()
    assert isinstance(m, StepMetrics)  # one twin, one step
    halted_at_s, ended = None, "ran to the end"
    if twin.board.halted:
        halted_at_s, ended = next((t, line) for t, line in twin.trace.events if line.startswith("Error:"))
    return TwinRun(gains, m.rise_time_s, m.overshoot_c, m.settling_time_2pct_s, halted_at_s, ended, run.t_s,
                   run.measured_c)


# The paper's platform runs Klipper (section 5.1). Klipper's verify_heater stops a heater whose reading has
# not gained 2 C within check_gain_time (20 s by default): eq. 15's 20 s dead time alone trips it, so the
# Klipper twin runs with check_gain_time 60 s, a setting a Klipper user gives a slow heater.
KLIPPER_CHECK_GAIN_TIME_S = 60.0
KLIPPER_MAX_TEMP_C = float(HEATER_0_MAXTEMP_C)  # the same ceiling as the Marlin twin's


def klipper_run(gains: Gains) -> TwinRun:
    """The eq. 15 experiment on the Klipper twin: Klipper's PID (no functional range), gains on its 0..255 scale."""
    setup = extruder_setup(make_plant(TWIN_PRESET, ambient_c=TWIN_FROM_C), pid_kp=gains.kp, pid_ki=gains.ki,
                           pid_kd=gains.kd, max_temp_c=KLIPPER_MAX_TEMP_C)
    setup = replace(setup, verify={"check_gain_time_s": KLIPPER_CHECK_GAIN_TIME_S})
    twin = KlipperTwin([setup])
    twin.set_target(setup.config.name, SETPOINT_C, at_s=0.0)
    twin.run_until(HORIZON_S)
    run = twin.result().hotend
    m = run.metrics()
    assert isinstance(m, StepMetrics)  # one twin, one step
    ended = "ran to the end" if not twin.halted else (twin.shutdown_message or "").split("\n")[0]
    return TwinRun(gains, m.rise_time_s, m.overshoot_c, m.settling_time_2pct_s, twin.shutdown_time_s, ended,
                   run.t_s, run.measured_c)


def largest_difference_c(runs: list[TwinRun]) -> float:
    """The largest gap between the runs' readings up to the first halt (0: the gains never acted)."""
    end_s = min((r.halted_at_s for r in runs if r.halted_at_s is not None), default=HORIZON_S)
    samples = [r.reading_c[r.t_s <= end_s] for r in runs]
    n = min(len(s) for s in samples)
    return float(np.max(np.ptp(np.array([s[:n] for s in samples]), axis=0)))


@dataclass(frozen=True)
class FullPowerHeatup:
    """Eq. 15 at full duty from TWIN_FROM_C until the reading enters Marlin's PID functional range,
    then off: the best a heater that can only heat can do once the PID may act."""

    reach_target_s: float  # the true temperature first at the set point
    enter_range_s: float  # the reading (the temperature, 20 s after the input) within the range
    temp_at_entry_c: float  # the temperature then
    peak_c: float  # the highest temperature after the input is switched off


def full_power_heatup(sample_s: float = SAMPLE_S) -> FullPowerHeatup:
    """Open loop: input 1 while the temperature is below SETPOINT_C - PID_FUNCTIONAL_RANGE_C, 0
    after; the input reaches the plant DEAD_TIME_S later (eq. 15's delay), so the heater keeps
    heating for that long after the switch."""
    ad, bd = _plant_matrices(sample_s)
    delay = round(DEAD_TIME_S / sample_s)
    steps = round(HORIZON_S / sample_s)
    commands = np.zeros(steps + delay)
    x = np.zeros(2)
    temps = np.empty(steps)
    switched = None
    for k in range(steps):
        temps[k] = TWIN_FROM_C + x[0]
        if switched is None and temps[k] >= SETPOINT_C - PID_FUNCTIONAL_RANGE_C:
            switched = k
        commands[k + delay] = 1.0 if switched is None else 0.0
        x = ad @ x + bd * commands[k]
    if switched is None:
        raise RuntimeError("the full-power heat-up never reaches the functional range")
    reach = int(np.argmax(temps >= SETPOINT_C))
    return FullPowerHeatup(reach * sample_s, switched * sample_s, float(temps[switched]), float(temps.max()))


# -- the command's and the page's report ----------------------------------------------------------

SMALL_TUNING = {"population": 20, "iterations": 40}  # the paper's 50 x 300 of 1000 s loops takes many minutes
PAPER_TUNING = {"population": 50, "iterations": 300}
LOOPS = (
    f"paper loop: eq. 15 under a continuous PID (N = {FILTER_N:g}, no output limit, step {SAMPLE_S} s), 0 -> "
    f"{SETPOINT_C:g} C, a {DISTURBANCE} input step at {DISTURBANCE_AT_S:g} s; no firmware and no firmware delay",
    f"firmware twin: the `{TWIN_PRESET}` preset (eq. 15, its {DEAD_TIME_S:g} s dead time, duty 1 = the model's input "
    f"1) behind the 10-bit ADC and the soft PWM of a heater that can only heat, Marlin's integer PID every 0.164 s, "
    f"{TWIN_FROM_C:g} -> {SETPOINT_C:g} C: the firmware's loop with its delays",
    "Klipper twin: the same plant under Klipper's host PID (klippy/extras/heaters.py, as the paper's platform runs "
    "it), its ADC reports every 0.3 s and the pwm 0.3 s later: Klipper's loop with its delays",
    "benchmark: F1-F23 as tools/tuning/benchfuncs.py defines them (no loop)",
)


def tuning(budget: Budget) -> dict[str, int]:
    if budget.iterations is not None:
        return {**PAPER_TUNING, "iterations": budget.iterations}
    return PAPER_TUNING if budget.name == PAPER else SMALL_TUNING


def steps(budget: Budget) -> int:
    """Progress calls of ``report``: the benchmark's runs, ALO, OCALO, the reference DE, 3 gain sets on 2 twins."""
    return seed002_benchmark.run_count(budget) + 3 + 2 * 3


@dataclass(frozen=True)
class Seed002Result:
    benchmark: Results
    pid: Reproduction
    twin: dict[str, TwinRun]  # Marlin's integer PID
    klipper: dict[str, TwinRun]  # Klipper's PID
    heatup: FullPowerHeatup
    tuning: dict[str, int]


def run(budget: Budget = SMALL_BUDGET, progress: Progress = no_progress) -> Seed002Result:
    bench = seed002_benchmark.rerun(budget, progress)
    settings = tuning(budget)
    pid = reproduce(progress=progress, **settings)
    gain_sets = {name: Gains(*row[3:]) for name, row in PRINTED_TABLE11.items()}
    gain_sets["reference DE"] = Gains.from_duty(*pid.reference.gains)
    twin, klipper = {}, {}
    for name, gains in gain_sets.items():
        twin[name] = twin_run(gains)
        progress(f"Marlin twin, {name}")
        klipper[name] = klipper_run(gains)
        progress(f"Klipper twin, {name}")
    return Seed002Result(bench, pid, twin, klipper, full_power_heatup(), settings)


_FIGURES = (("overshoot_pct", "overshoot %", 2), ("peak_time_s", "peak time s", 1), ("rise_time_s", "rise time s", 1),
            ("settling_time_s", "settling time 2 % s", 1))


def _section4_rows(res: Seed002Result) -> list[Verdict]:
    pid, t = res.pid, res.tuning
    budget_words = f"ALO/OCALO on Q over [0, 1e5]^3, population {t['population']} x {t['iterations']} iterations, seed 0"
    rows = []
    for name in ("OCALO", "ALO"):
        ours = pid.ours[name]
        for key, label, decimals in _FIGURES:
            printed, value = PRINTED_TABLE9[name][key], getattr(ours, key)
            agrees = within(value, printed, 0.05 * abs(printed))
            why = budget_words + (f"; our Q {num(ours.q, 1)} against the reference DE's {num(pid.reference.q, 1)}"
                                  if not agrees else "; +-5 %")
            if value is None:
                why = f"{budget_words}: our loop never reaches the band; Q {num(ours.q, 1)}"
            rows.append(Verdict(f"table 9, {name}", label, f"{printed}", num(value, decimals),
                                REPRODUCED if agrees else DIFFERS, why))
        max_c, recovery_s = PRINTED_TABLE10[name]
        rows.append(Verdict(f"table 10, {name}", "max after the disturbance C", f"{max_c}",
                            num(ours.max_after_disturbance_c), REPRODUCED if within(ours.max_after_disturbance_c,
                                                                                    max_c, 0.05 * max_c) else DIFFERS,
                            budget_words))
        settled = ours.settling_time_s is not None
        recovered = ours.recovery_time_s is not None
        agrees = settled and (recovery_s is None) == (not recovered) and (
            recovery_s is None or within(ours.recovery_time_s, recovery_s, 0.05 * recovery_s))
        rows.append(Verdict(f"table 10, {name}", "recovery s", "-" if recovery_s is None else f"{recovery_s:g}",
                            num(ours.recovery_time_s, 1), REPRODUCED if agrees else DIFFERS,
                            budget_words + ("" if settled else ": our loop never reached the band before the "
                                                                 "disturbance")))
    for name, n in pid.printed_gains_on_model.items():
        overshoot, peak_s, stable_s = PRINTED_TABLE11[name][:3]
        rows.append(Verdict(f"table 11, {name}", "overshoot % (platform) / on eq. 15", f"{overshoot:g}",
                            num(n.overshoot_pct), DIFFERS if n.settling_time_s is None else REPRODUCED,
                            "the platform's printed gains / 255 in the paper's own loop do not settle: the model the "
                            "paper tunes on does not describe its platform" if n.settling_time_s is None else
                            "the platform's gains / 255 in the paper's loop"))
    claims = printed_claims()
    if claims:
        rows.append(Verdict("section 4.4", "OCALO-PID has the smallest peak after the disturbance",
                            f"OCALO {PRINTED_TABLE10['OCALO'][0]} C", "-", IMPOSSIBLE,
                            claims[0].replace("section 4.4 says OCALO-PID has the smallest maximum peak after the "
                                              "disturbance, but ", ""), claim=True))
    rows += [Verdict("table 8 / eq. 15", "the identified model", "table 8", "eq. 15", DIFFERS, line)
             for line in model_consistency()]
    return rows


def verdicts(res: Seed002Result, budget: Budget) -> list[Verdict]:
    return seed002_benchmark.benchmark_verdicts(res.benchmark, budget) + _section4_rows(res)


def _notes(res: Seed002Result) -> list[str]:
    runs = list(res.twin.values())
    heat = res.heatup
    notes = [seed002_benchmark.summary_note(res.benchmark)]
    if all(r.halted_at_s is not None for r in runs):
        notes.append(
            f"on the firmware twin every gain set halts (at {', '.join(num(r.halted_at_s, 1) for r in runs)} s), and "
            f"their readings are the same until then (largest difference {num(largest_difference_c(runs))} C): "
            f"Marlin's PID holds full power while the reading is more than PID_FUNCTIONAL_RANGE "
            f"({PID_FUNCTIONAL_RANGE_C} C) below the target, so no gain has acted before the halt")
    notes.append(
        f"why no gains can run on eq. 15 under Marlin's PID: at full power eq. 15 (a gain of "
        f"{num(PLANT_NUM / PLANT_DEN[2], 0)} C per unit of duty) reaches {SETPOINT_C:g} C at {num(heat.reach_target_s, 1)} "
        f"s; the reading enters the functional range at {num(heat.enter_range_s, 1)} s ({num(heat.temp_at_entry_c, 1)} "
        f"C), and switched off then the heater still receives {DEAD_TIME_S:g} s of full power already on its way "
        f"(the dead time): eq. 15 peaks at {num(heat.peak_c, 1)} C, past MAXTEMP ({HEATER_0_MAXTEMP_C} C), whatever "
        "the gains do after")
    saturated = {name: COUNTS_PER_DUTY / row[3] for name, row in PRINTED_TABLE11.items()}
    ran = [name for name, r in res.klipper.items() if r.halted_at_s is None]
    notes.append(
        "on the Klipper twin (the paper's platform firmware: no functional range) the PID is saturated while Kp x "
        "error exceeds full power, i.e. until the error is below "
        + ", ".join(f"{num(e, 1)} C ({name})" for name, e in saturated.items())
        + ": the printed gains make the same full-power heat-up; "
        + (f"{', '.join(ran)} ran to the end: gains small enough to stay off full power run on this plant"
           if ran else "no gain set ran to the end"))
    return notes


def report(budget: Budget = SMALL_BUDGET, progress: Progress = no_progress) -> SeedReport[Seed002Result]:
    """Seed 002 re-run: the benchmark's printed values and ordering, section 4 beside ours, the twin."""
    res = run(budget, progress)
    s, t = seed002_benchmark.settings(budget), res.tuning
    twin = Table(
        f"Firmware twin (`{TWIN_PRESET}`): table 11's platform gains as printed (0..255, the firmware's scale) and "
        "the reference DE's:",
        ("gains", "Kp / Ki / Kd", "rise s", "peak C above target", "settling 2 % s", "firmware"),
        tuple((name, f"{num(r.gains.kp, 3)} / {num(r.gains.ki, 4)} / {num(r.gains.kd, 3)}", num(r.rise_time_s, 1),
               num(r.overshoot_c, 1), num(r.settling_time_2pct_s, 1),
               r.ended if r.halted_at_s is None else f"halted at {num(r.halted_at_s, 1)} s: {r.ended}")
              for name, r in res.twin.items()))
    klipper = Table(
        f"Klipper twin (`{TWIN_PRESET}`, Klipper's PID as the paper's platform runs it, verify_heater's "
        f"check_gain_time {KLIPPER_CHECK_GAIN_TIME_S:g} s, max_temp {KLIPPER_MAX_TEMP_C:g} C):",
        ("gains", "rise s", "peak C above target", "settling 2 % s", "firmware"),
        tuple((name, num(r.rise_time_s, 1), num(r.overshoot_c, 1), num(r.settling_time_2pct_s, 1),
               r.ended if r.halted_at_s is None else f"halted at {num(r.halted_at_s, 1)} s: {r.ended}")
              for name, r in res.klipper.items()))
    ref = res.pid.reference
    loop = Table(
        "Section 4 in the paper's loop: ours and the reference (DE on Q in a box around the gains that matter):",
        ("gains", "Kp / Ki / Kd (duty per C)", "Q", "overshoot %", "rise s", "settling 2 % s", "max after "
         "disturbance C", "recovery s", "lowest input"),
        tuple((name, " / ".join(f"{g:.4g}" for g in n.gains), num(n.q, 1), num(n.overshoot_pct), num(n.rise_time_s, 1),
               num(n.settling_time_s, 1), num(n.max_after_disturbance_c), num(n.recovery_time_s, 1),
               num(n.min_control, 2))
              for name, n in (*res.pid.ours.items(), ("reference DE", ref),
                              *((f"{k} table 11 / 255", v) for k, v in res.pid.printed_gains_on_model.items()))))
    return SeedReport(
        "002", "High-speed 3D printing temperature control with an improved ALO (OCALO)",
        f"{budget}: benchmark {s['runs']} runs of population {s['population']} x {s['iterations']} iterations (the "
        f"paper: {seed002_benchmark.PAPER_RUNS} runs of 50 x 300); section 4 population {t['population']} x "
        f"{t['iterations']} (the paper's 50 x 300 with --budget paper); seed 0",
        LOOPS, tuple(verdicts(res, budget)), res, (loop, twin, klipper), tuple(_notes(res)))


if __name__ == "__main__":  # python -m tools.seeds.seed002: the same as python -m tools.seeds 002
    from tools.seeds.command import main_for

    sys.exit(main_for("002", report, steps))
