"""Twin against real hardware logs (shared/hardware_logs, README sections A, B, E): three checks.

1. ``open_loop_check``: the onionheater hotend fitted (three_node, ambient 21.4 C) on the no-fan
   pulse test's first pulse, then the two part-fan runs predicted with one added parameter, the
   fan-on loss coefficient (fan_ambient_xfer_w_k), fitted on one fan run and tested on the other.
2. ``closed_loop_check``: a Klipper Stats printer's heater: two_node fitted on one heat-up segment,
   then KlipperTwin with the printer's own gains, max_power, thermistor, pullup, smooth_time and
   pwm_cycle_time replays the logged targets of another heat-up (or the same one when the log has
   only one); heat-up time to target-2 C, overshoot, hold RMSE (twin - log) and steady pwm.
3. ``autotune_check``: KlipperTwin.pid_calibrate on that fitted plant, Tu against the printer's
   saved calibration (Tu = 2 Kp / Ki).

Every function raises LogError / NotFittable / Unusable with one sentence when a log cannot serve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from firmware_port.klipper import HeaterConfig
from firmware_port.klipper.heater import (
    CommandError,
    MIN_PWM_CHANGE_BEFORE_2026_03,
    PWM_RESEND_2025_04,
    PWM_RESEND_BEFORE_2025_04,
)
from firmware_port.thermistor import KLIPPER_SENSORS
from tools.ident.fit import fit_model
from tools.ident.result import FitResult
from tools.ident.segments import MIN_HEATUP_S, Segment, log_segments
from tools.logs import (
    HeattestLog,
    StatsLog,
    hardware_logs_dir,
    load_log,
    parse_heattest,
)
from tools.ident.runs import Run, run_response
from twin.klipper_twin import PULLUP_OHM, PWM_CYCLE_TIME_S, HeaterSetup, KlipperTwin
from twin.plants import Lumped, Plant

ONION_AMBIENT_C = 21.4  # the author's room temperature (README B)
ONION_FAN = 1.0  # "part fan on" (README B): its speed is not logged; taken as full
ONION_NO_FAN = "klipper_heattest_onionheater_heattest_200.csv"
ONION_FAN_FIT = "klipper_heattest_onionheater_heattest_fan_200.csv"
ONION_FAN_TEST = "klipper_heattest_onionheater_heattest_fan_200_2.csv"
ONION_FILES = (ONION_NO_FAN, ONION_FAN_FIT, ONION_FAN_TEST, "klipper_heattest_onionheater_sample_trace.csv")

GOAL_OPEN_LOOP_RMSE_C = 3.0
GOAL_HEATUP_REL = 0.10
GOAL_OVERSHOOT_C = 1.5
GOAL_HOLD_RMSE_C = 1.0
GOAL_TU_REL = 0.15

NEAR_TARGET_C = 2.0  # heat-up time: to target - this
STEADY_LAST_S = 60.0
LEAD_IN_S = 60.0  # a replay starts this long before the heat-up's target change (where the log has it)
HOLD_S = 300.0  # a replay runs this long after the log first reaches target - 2 C (or to a target change)  # steady pwm: the mean over the last this-many seconds of the hold

FALLBACK_SENSOR = "Generic 3950"  # for a custom thermistor table the twin does not have (a B3950)
CALIBRATION_TARGET_C = {"extruder": 200.0, "heater_bed": 60.0}  # not stated in any log here
# No log states its calibration temperature: the twin's Tu is also given at the ends of the band
# where printers are usually calibrated (PLA to PETG/ABS hotend temperatures, PLA to ABS beds).
CALIBRATION_BAND_C = {"extruder": (180.0, 240.0), "heater_bed": (50.0, 100.0)}

# The Stats printers (README A); (file, heater) pairs for the closed-loop and autotune checks.
STATS_FILES = (
    "klippy_stats_chesleavens_cartesian_stm32f103.csv",
    "klippy_stats_shreypatel_cartesian_stm32f407.csv",
    "klippy_stats_ianryeng_corexy_ebbcan.csv",
    "klippy_stats_icodextrin_ender5_creality427.csv",
    "klippy_stats_jc1rb_manta_m8p.csv",
    "klippy_stats_claudermilk_rp2040_umbilical.csv",
    "klippy_stats_jakew02_redoubt_longprint.csv",
    "klippy_stats_pdegrazia_kingroon_kp3s_a.csv",
    "klippy_stats_pdegrazia_kingroon_kp3s_b.csv",
)
HEATERS = ("extruder", "heater_bed")
# README E: the self-consistent pairs (a heat-up trace and a PID_CALIBRATE result in the same log)
AUTOTUNE_PAIRS = (
    ("klippy_stats_chesleavens_cartesian_stm32f103.csv", "extruder"),
    ("klippy_stats_chesleavens_cartesian_stm32f103.csv", "heater_bed"),
    ("klippy_stats_ianryeng_corexy_ebbcan.csv", "extruder"),
    ("klippy_stats_ianryeng_corexy_ebbcan.csv", "heater_bed"),
    ("klippy_stats_icodextrin_ender5_creality427.csv", "extruder"),
    ("klippy_stats_icodextrin_ender5_creality427.csv", "heater_bed"),
    ("klippy_stats_jc1rb_manta_m8p.csv", "extruder"),
    ("klippy_stats_claudermilk_rp2040_umbilical.csv", "extruder"),
    ("klippy_stats_claudermilk_rp2040_umbilical.csv", "heater_bed"),
    ("klippy_stats_jakew02_redoubt_longprint.csv", "extruder"),
    ("klippy_stats_jakew02_redoubt_longprint.csv", "heater_bed"),
)


class Unusable(ValueError):
    """A log (or heater of one) this check cannot use; the message says why."""


def rel_err(twin: float, log: float) -> float:
    return (twin - log) / log if log else math.inf


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)


# --- 1. open loop ------------------------------------------------------------------------------


@dataclass
class OpenLoopResult:
    fit: FitResult  # three_node on the no-fan first pulse
    fit_segment: str
    fit_rmse_c: float
    fit_max_err_c: float
    # one row per direction: fan coefficient fitted on run "fitted_on", predicted run "predicted"
    rows: list[dict] = field(default_factory=list)
    # the no-fan session's later pulse from the same fit: how a later pulse misses with no fan change
    later_pulse: dict = field(default_factory=dict)
    traces: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)  # t, log, twin


def _response(fit: FitResult, fan_xfer_w_k: float, run: Run) -> np.ndarray:
    """The fitted plant with fan loss F at the run's samples, from the state the run declares."""
    lumped = fit.spec()
    assert isinstance(lumped, Lumped)  # a fan loss needs the lumped models
    spec = replace(lumped, fan_ambient_xfer_w_k=float(fan_xfer_w_k))
    return run_response(spec, fit.model, fit.values["ambient_c"], run)


def _fit_fan(fit: FitResult, run: Run) -> float:
    """The fan loss F (W/K at the run's fan) that fits the run best, its session carried through."""
    import scipy.optimize  # here: a command's start-up needs no scipy
    a = fit.values["ambient_xfer_w_k"]
    best = scipy.optimize.minimize_scalar(
        lambda f: float(np.mean(np.square(_response(fit, f, run) - run.temp_c))),
        bounds=(0.5 * a, 6.0 * a), method="bounded", options={"xatol": 1e-4})
    return float(best.x)


def _errors(pred: np.ndarray, logged: np.ndarray) -> tuple[float, float]:
    err = pred - logged
    return float(np.sqrt(np.mean(err ** 2))), float(np.max(np.abs(err)))


def onion_fan_runs(logs_dir: Path) -> dict[str, Run]:
    """The two fan runs as they declare themselves (README B): part fan on, one session: the second
    file's clock continues the first's, so it starts where the first left the hotend."""
    first, second = (parse_heattest(logs_dir / name) for name in (ONION_FAN_FIT, ONION_FAN_TEST))
    run1 = Run(ONION_FAN_FIT, first.t_s, first.temp_c, first.pwm, fan=ONION_FAN)
    return {ONION_FAN_FIT: run1,
            ONION_FAN_TEST: Run(ONION_FAN_TEST, second.t_s, second.temp_c, second.pwm, fan=ONION_FAN, follows=run1)}


def _later_pulse(fit: FitResult, log: HeattestLog) -> dict:
    """The no-fan log's second pulse predicted after its first (state carried) and from a settled
    start: a later pulse of a session with no fan in either, the fan runs' situation without a fan change."""
    on = np.flatnonzero(np.diff(log.pwm) > 0) + 1  # the samples where a pulse starts
    split = int(on[1]) - 1  # the second pulse's run starts one sample before it, as the fan files do
    first = Run("first pulse", log.t_s[:split], log.temp_c[:split], log.pwm[:split])
    runs = {start: Run("second pulse", log.t_s[split:], log.temp_c[split:], log.pwm[split:], follows=follows)
            for start, follows in (("after", first), ("settled", None))}
    errors = {start: _errors(_response(fit, fit.values["ambient_xfer_w_k"], r), r.temp_c) for start, r in runs.items()}
    pred = _response(fit, fit.values["ambient_xfer_w_k"], runs["after"])
    return {"t_s": float(log.t_s[split]), "rmse_after_c": errors["after"][0], "rmse_settled_c": errors["settled"][0],
            "peak_log_c": float(runs["after"].temp_c.max()), "peak_twin_c": float(pred.max())}


def open_loop_check(logs_dir: Path | None = None, model: str = "three_node",
                    both_ways: bool = True) -> OpenLoopResult:
    """Fit on the no-fan first pulse; fit the fan coefficient on one fan run and predict the other
    over the whole run, each from the state it declares (both ways round unless both_ways is False);
    and the no-fan second pulse from the same fit."""
    logs_dir = hardware_logs_dir() if logs_dir is None else Path(logs_dir)
    no_fan = parse_heattest(logs_dir / ONION_NO_FAN)
    _, segments = log_segments(no_fan)
    seg = segments[0]
    fit = fit_model(model, seg.t_s, seg.temp_c, seg.duty, ONION_AMBIENT_C)
    result = OpenLoopResult(fit, seg.label, *_errors(fit.simulate(seg.t_s, seg.duty), seg.temp_c),
                            later_pulse=_later_pulse(fit, no_fan))
    result.traces[ONION_NO_FAN] = (seg.t_s, seg.temp_c, fit.simulate(seg.t_s, seg.duty))
    runs = onion_fan_runs(logs_dir)
    pairs = [(ONION_FAN_FIT, ONION_FAN_TEST)] + ([(ONION_FAN_TEST, ONION_FAN_FIT)] if both_ways else [])
    for fitted_on, predicted in pairs:
        f = _fit_fan(fit, runs[fitted_on])
        own = _errors(_response(fit, f, runs[fitted_on]), runs[fitted_on].temp_c)
        run = runs[predicted]
        pred = _response(fit, f, run)
        rmse, max_err = _errors(pred, run.temp_c)
        result.rows.append({"fitted_on": fitted_on, "predicted": predicted, "start": run.start, "fan": run.fan,
                            "fan_xfer_w_k": f, "no_fan_xfer_w_k": fit.values["ambient_xfer_w_k"],
                            "fit_rmse_c": own[0], "rmse_c": rmse, "max_err_c": max_err,
                            "peak_log_c": float(run.temp_c.max()), "peak_twin_c": float(pred.max()),
                            "passed": rmse <= GOAL_OPEN_LOOP_RMSE_C})
        result.traces.setdefault(predicted, (run.t_s, run.temp_c, pred))
    return result


# --- 2. closed loop ----------------------------------------------------------------------------


@dataclass
class HeaterInfo:
    kp: float
    ki: float
    kd: float
    max_power: float
    sensor: str
    sensor_note: str
    pullup_ohm: float
    smooth_time_s: float
    pwm_cycle_time_s: float
    min_temp_c: float
    max_temp_c: float
    pwm_resend: str


def heater_info(log: StatsLog, heater: str) -> HeaterInfo:
    cfg = log.meta["config"].get(heater)
    if not cfg:
        raise Unusable(f"no [{heater}] section in the log's config dump")
    if cfg.get("control", "pid") != "pid" or not all(k in cfg for k in ("pid_kp", "pid_ki", "pid_kd")):
        raise Unusable(f"[{heater}] is not PID-controlled with gains in the config dump")
    sensor = cfg.get("sensor_type", "")
    note = ""
    if sensor not in KLIPPER_SENSORS:
        note = f"'{sensor}' is a custom table the twin lacks: {FALLBACK_SENSOR} used"
        sensor = FALLBACK_SENSOR
    version = log.meta.get("klipper_version") or ""
    # README A: v0.13.0-504 onward (ianryeng) MAX_HEAT_TIME 3 s; older 5 s
    resend = PWM_RESEND_2025_04 if version.startswith("v0.13") else PWM_RESEND_BEFORE_2025_04
    return HeaterInfo(float(cfg["pid_kp"]), float(cfg["pid_ki"]), float(cfg["pid_kd"]),
                      float(cfg.get("max_power", 1.0)), sensor, note,
                      float(cfg.get("pullup_resistor", PULLUP_OHM)), float(cfg.get("smooth_time", 1.0)),
                      float(cfg.get("pwm_cycle_time", PWM_CYCLE_TIME_S)),
                      float(cfg.get("min_temp", 0.0)), float(cfg.get("max_temp", 300.0)), resend)


def make_setup(info: HeaterInfo, heater: str, plant) -> HeaterSetup:
    config = HeaterConfig(heater, info.min_temp_c, info.max_temp_c, pid_kp=info.kp, pid_ki=info.ki, pid_kd=info.kd,
                          max_power=info.max_power, smooth_time_s=info.smooth_time_s, pwm_resend=info.pwm_resend,
                          min_pwm_change=MIN_PWM_CHANGE_BEFORE_2026_03)
    return HeaterSetup(config, plant, info.sensor, info.pullup_ohm, min(info.pwm_cycle_time_s, config.pwm_delay_s))


@dataclass
class Window:
    """One heat-up of the log: the gap-free samples from the target change to the segment's end."""

    label: str
    session: int
    t_s: np.ndarray
    target_c: np.ndarray
    temp_c: np.ndarray
    pwm: np.ndarray
    # the same part's samples up to LEAD_IN_S before the target change: replayed, not compared
    lead_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    lead_target_c: np.ndarray = field(default_factory=lambda: np.empty(0))
    lead_temp_c: np.ndarray = field(default_factory=lambda: np.empty(0))


def heatup_windows(log: StatsLog, heater: str) -> tuple[list, list[Window]]:
    """The fit segments of a heater and, for those that are heat-ups (a run at max_power of
    MIN_HEATUP_S or more to a target well above the start), the replay windows."""
    try:
        _, segments = log_segments(log, heater)
    except ValueError as error:
        raise Unusable(str(error)) from None
    windows = []
    for seg in segments:
        if seg.full_power_s < MIN_HEATUP_S:
            continue
        for index, heaters in enumerate(log.sessions):
            series = heaters.get(heater)
            if series is None:
                continue
            for part in series.segments():
                i = int(np.searchsorted(part.t_s, seg.t_s[0]))
                if i >= len(part.t_s) or part.t_s[i] != seg.t_s[0] or part.temp_c[i] != seg.temp_c[0]:
                    continue
                j = i + len(seg.t_s)
                target = part.target_c[j - 1]
                # extend to the hold: while the target stays, up to HOLD_S after the first reach
                reach = np.flatnonzero((part.temp_c[i:] >= target - NEAR_TARGET_C)
                                       | (part.target_c[i:] != target))
                end_s = part.t_s[i + int(reach[0])] + HOLD_S if reach.size else part.t_s[-1]
                while j < len(part.t_s) and part.target_c[j] == target and part.t_s[j] <= end_s:
                    j += 1
                start = i
                while start > 0 and part.target_c[start - 1] == target:
                    start -= 1
                start = max(start, i - 30)  # the target set at most ~30 s before full power
                if target - part.temp_c[start] < 10.0 or part.target_c[start] != target:
                    continue
                if not np.any(part.temp_c[start:j] >= target - NEAR_TARGET_C):
                    continue  # the log never reaches this target: nothing to compare
                # the lead-in: back LEAD_IN_S, from after any 0.0 (Klipper's reading before its first report)
                unread = np.flatnonzero(part.temp_c[:start] <= 0.0)
                first = max(int(np.searchsorted(part.t_s, part.t_s[start] - LEAD_IN_S)),
                            int(unread[-1]) + 1 if unread.size else 0)
                lead = slice(first, start)
                windows.append(Window(f"session {index}, {part.t_s[start]:.0f}..{part.t_s[j - 1]:.0f} s", index,
                                      part.t_s[start:j], part.target_c[start:j], part.temp_c[start:j],
                                      part.pwm[start:j], part.t_s[lead], part.target_c[lead], part.temp_c[lead]))
    return segments, windows


@dataclass
class ReplayMetrics:
    heatup_s: float  # from the target change to target - 2 C
    overshoot_c: float  # max temp - target after reaching target - 2 C
    hold_rms_c: float  # temp about the target during the hold (each trace on its own)
    steady_pwm: float  # mean pwm over the last STEADY_LAST_S of the hold


def replay_metrics(t_s, temp_c, pwm, target_c: float) -> ReplayMetrics:
    t, temp, pwm = (np.asarray(a, float) for a in (t_s, temp_c, pwm))
    reached = np.flatnonzero(temp >= target_c - NEAR_TARGET_C)
    if not reached.size:
        return ReplayMetrics(math.nan, math.nan, math.nan, float(np.mean(pwm[t >= t[-1] - STEADY_LAST_S])))
    k = int(reached[0])
    if k > 0:  # interpolate the crossing
        y0, y1 = temp[k - 1], temp[k]
        heatup = t[k - 1] + (t[k] - t[k - 1]) * (target_c - NEAR_TARGET_C - y0) / (y1 - y0) - t[0]
    else:
        heatup = 0.0
    hold = t >= t[k]
    return ReplayMetrics(float(heatup), float(np.max(temp[hold]) - target_c),
                         float(np.sqrt(np.mean((temp[hold] - target_c) ** 2))),
                         float(np.mean(pwm[hold & (t >= t[-1] - STEADY_LAST_S)])))


@dataclass
class ClosedLoopResult:
    file: str
    heater: str
    fit: FitResult
    fit_label: str
    replay_label: str
    same_segment: bool
    info: HeaterInfo
    log: ReplayMetrics
    twin: ReplayMetrics
    hold_rmse_c: float  # twin - log over the hold (the log's samples from its first reach of target - 2 C)
    target_c: float
    shutdown: str | None
    trace: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # t, log temp, twin temp, log pwm, twin pwm
    shutdown_s: float | None = None  # when the twin shut down, on the trace's clock

    @property
    def heatup_rel(self) -> float:
        return rel_err(self.twin.heatup_s, self.log.heatup_s)

    @property
    def overshoot_diff_c(self) -> float:
        return self.twin.overshoot_c - self.log.overshoot_c

    @property
    def checks(self) -> dict[str, bool]:
        return {"heat-up": _finite(self.heatup_rel) and abs(self.heatup_rel) <= GOAL_HEATUP_REL,
                "overshoot": _finite(self.overshoot_diff_c) and abs(self.overshoot_diff_c) <= GOAL_OVERSHOOT_C,
                "hold": _finite(self.hold_rmse_c) and self.hold_rmse_c <= GOAL_HOLD_RMSE_C}


def fit_heater(log: StatsLog, heater: str, model: str = "two_node") -> tuple[FitResult, Segment, list[Window]]:
    """two_node on the heat-up segment with the most time at max_power; the replay windows."""
    segments, windows = heatup_windows(log, heater)
    if not windows:
        raise Unusable(f"{heater}: no heat-up (a run at max_power of {MIN_HEATUP_S:g} s or more to a new "
                       "target at least 10 C above the start)")
    heatups = [s for s in segments if s.full_power_s >= MIN_HEATUP_S and not s.cools_at_full_power]
    seg = max(heatups, key=lambda s: (s.temp_c.max() - s.temp_c[0]))
    try:
        fit = fit_model(model, seg.t_s, seg.temp_c, seg.duty)
    except ValueError as error:
        raise Unusable(f"{heater}: the fit failed: {error}") from None
    return fit, seg, windows


def target_times_s(t_s: np.ndarray, target_c: np.ndarray) -> np.ndarray:
    """When the logged targets took effect: a change first shown at a Stats line happened between
    that line and the one before, so halfway (the first sample's own time for the first)."""
    return np.r_[t_s[:1], np.where(np.diff(target_c) != 0, (t_s[:-1] + t_s[1:]) / 2.0, t_s[1:])]


def replay(fit: FitResult, info: HeaterInfo, heater: str, window: Window):
    """KlipperTwin through the logged targets of the window and its lead-in, from the lead-in's
    first reading (the twin's first report comes ADC_FIRST_SAMPLE_S after its start and its PID
    starts from Klipper's initial state: the lead-in settles both as the printer's were when the
    target changed); the twin at the window's instants, and its shutdown (message, time from the window's start)."""
    t_all = np.r_[window.lead_t_s, window.t_s]
    temp0 = float(np.r_[window.lead_temp_c, window.temp_c][0])
    plant = Plant(fit.model, fit.spec(), fit.values["ambient_c"], temp0)
    twin = KlipperTwin([make_setup(info, heater, plant)])
    targets = np.r_[window.lead_target_c, window.target_c]
    twin.schedule_targets(heater, target_times_s(t_all - t_all[0], targets).tolist(), targets.tolist())
    rel = window.t_s - t_all[0]
    twin.run_until(float(rel[-1]) + 0.01)
    rt, rtemp, rpwm = (twin.column(heater, f) for f in ("t_s", "temp_c", "pwm"))
    idx = np.searchsorted(rt, rel, side="right") - 1
    ok = idx >= 0
    twin_temp = np.where(ok, rtemp[np.maximum(idx, 0)], temp0)
    twin_pwm = np.where(ok, rpwm[np.maximum(idx, 0)], 0.0)
    shutdown_s = None if twin.shutdown_time_s is None else twin.shutdown_time_s - (window.t_s[0] - t_all[0])
    return twin_temp, twin_pwm, twin.shutdown_message, shutdown_s


def _load_stats(path: Path) -> StatsLog:
    log = load_log(path)
    if not isinstance(log, StatsLog):
        raise Unusable("not a Klipper Stats log")
    return log


def _session(label: str) -> int:
    """The session number of a segment's label ("session 1, 1039.5..1158.5 s")."""
    return int(label.split(",")[0].split()[1])


def overlaps(window: Window, seg: Segment) -> bool:
    return window.session == _session(seg.label) and window.t_s[0] <= seg.t_s[-1] and seg.t_s[0] <= window.t_s[-1]


def score_replay(file: str, heater: str, fit: FitResult, fit_label: str, info: HeaterInfo, window: Window,
                 same_segment: bool) -> ClosedLoopResult:
    """Replay one window on one fitted plant and measure both traces."""
    target = float(window.target_c[-1])
    twin_temp, twin_pwm, shutdown, shutdown_s = replay(fit, info, heater, window)
    rel = window.t_s - window.t_s[0]
    log_m = replay_metrics(rel, window.temp_c, window.pwm, target)
    twin_m = replay_metrics(rel, twin_temp, twin_pwm, target)
    reached = np.flatnonzero(window.temp_c >= target - NEAR_TARGET_C)
    hold = slice(int(reached[0]) if reached.size else len(rel), None)
    err = twin_temp[hold] - window.temp_c[hold]
    hold_rmse = float(np.sqrt(np.mean(err ** 2))) if err.size else math.nan
    return ClosedLoopResult(file, heater, fit, fit_label, window.label, same_segment, info, log_m, twin_m, hold_rmse,
                            target, shutdown, (rel, window.temp_c, twin_temp, window.pwm, twin_pwm), shutdown_s)


def closed_loop_check(path: str | Path, heater: str) -> ClosedLoopResult:
    """The heater's fitted plant replaying its first heat-up other than the fitted one (held-out),
    else the fitted one (in-sample)."""
    path = Path(path)
    log = _load_stats(path)
    info = heater_info(log, heater)
    fit, seg, windows = fit_heater(log, heater)
    others = [w for w in windows if not overlaps(w, seg)]
    return score_replay(path.name, heater, fit, seg.label, info, (others or windows)[0], not others)


@dataclass
class MissEvidence:
    """What the log says about a replay that misses. Held-out: the same heat-up replayed on a plant
    fitted to itself (in-sample), and the two fits' power-free numbers side by side (held-out fit
    first): the heating rate at full power P / C, with how many standard errors apart, and the
    steady duty the plant needs at the replayed target, (target - ambient) / rise at full power."""

    result: ClosedLoopResult
    own: ClosedLoopResult | None = None  # None: the replay was in-sample already
    heating_rate_c_s: tuple[float, float] = (math.nan, math.nan)
    heating_rate_sigmas: float = math.nan  # |difference| / sqrt(sum of squared standard errors)
    hold_duty: tuple[float, float] = (math.nan, math.nan)


def _heating_rate(fit: FitResult) -> tuple[float, float]:
    """P / C and its standard error (delta method on C; the power is held)."""
    rate = fit.derived()["heating_rate_c_s"]
    return rate, rate * fit.std_errors["block_heat_capacity_j_k"] / fit.params["block_heat_capacity_j_k"]


def _hold_duty(fit: FitResult, target_c: float) -> float:
    return (target_c - fit.values["ambient_c"]) / fit.derived()["rise_at_full_power_c"]


def miss_evidence(path: str | Path, result: ClosedLoopResult) -> MissEvidence:
    """For a held-out replay: the replayed heat-up's own segment fitted the same way and replayed
    (does the model miss that heat-up even in-sample?) and the two fits compared."""
    path = Path(path)
    if result.same_segment:
        return MissEvidence(result)
    log = _load_stats(path)
    segments, windows = heatup_windows(log, result.heater)
    window = next(w for w in windows if w.label == result.replay_label)
    seg = next(s for s in segments if s.full_power_s >= MIN_HEATUP_S and overlaps(window, s))
    try:
        own_fit = fit_model(result.fit.model, seg.t_s, seg.temp_c, seg.duty)
    except ValueError as error:
        raise Unusable(f"{result.heater}: the fit of the replayed heat-up failed: {error}") from None
    own = score_replay(path.name, result.heater, own_fit, seg.label, result.info, window, True)
    (rate_a, se_a), (rate_b, se_b) = _heating_rate(result.fit), _heating_rate(own_fit)
    return MissEvidence(result, own, (rate_a, rate_b), abs(rate_a - rate_b) / math.hypot(se_a, se_b),
                        (_hold_duty(result.fit, result.target_c), _hold_duty(own_fit, result.target_c)))


# --- 3. autotune -------------------------------------------------------------------------------


@dataclass
class AutotuneResult:
    file: str
    heater: str
    target_c: float
    tu_log_s: float  # 2 Kp / Ki of the printer's saved gains
    tu_twin_s: float
    p2p_log_c: float
    p2p_twin_c: float
    twin_gains: tuple[float, float, float]
    tu_band_s: tuple[float, float] = (math.nan, math.nan)  # the twin's Tu at the CALIBRATION_BAND_C ends

    @property
    def tu_rel(self) -> float:
        return rel_err(self.tu_twin_s, self.tu_log_s)

    @property
    def passed(self) -> bool:
        return _finite(self.tu_rel) and abs(self.tu_rel) <= GOAL_TU_REL

    @property
    def passed_in_band(self) -> bool:
        """The log's Tu within 15 % of the range the twin's Tu spans at the band's two ends."""
        ends = [t for t in self.tu_band_s if _finite(t)]
        return bool(ends) and min(ends) * (1 - GOAL_TU_REL) <= self.tu_log_s <= max(ends) * (1 + GOAL_TU_REL)


def autotune_check(path: str | Path, heater: str, fit: FitResult | None = None,
                   model: str = "two_node") -> AutotuneResult:
    path = Path(path)
    log = load_log(path)
    if not isinstance(log, StatsLog):
        raise Unusable("not a Klipper Stats log")
    info = heater_info(log, heater)
    if fit is None:
        fit, _, _ = fit_heater(log, heater, model)
    tu_s, p2p_c, gains = _pid_calibrate(fit, info, heater, CALIBRATION_TARGET_C[heater])
    band = tuple(_band_tu(fit, info, heater, t) for t in CALIBRATION_BAND_C[heater])
    p2p_log = 8.0 * info.max_power * 0.6 * 255.0 / (math.pi * info.kp)
    return AutotuneResult(path.name, heater, CALIBRATION_TARGET_C[heater], 2.0 * info.kp / info.ki, tu_s, p2p_log,
                          p2p_c, gains, band)  # type: ignore[arg-type]


def _band_tu(fit: FitResult, info: HeaterInfo, heater: str, target: float) -> float:
    """The twin's Tu at a band end; NaN where the heater cannot calibrate there (beyond its max_temp)."""
    try:
        return _pid_calibrate(fit, info, heater, target)[0]
    except Unusable:
        return math.nan


def _pid_calibrate(fit: FitResult, info: HeaterInfo, heater: str, target: float):
    """KlipperTwin.pid_calibrate on the fitted plant from ambient: (Tu, peak-to-peak, gains)."""
    ambient = fit.values["ambient_c"]
    plant = Plant(fit.model, fit.spec(), ambient, ambient)
    twin = KlipperTwin([make_setup(info, heater, plant)])
    try:
        result = twin.pid_calibrate(heater, target)
    except CommandError as error:  # e.g. verify_heater or the ADC range check stopped the twin
        why = f"; {twin.shutdown_message.splitlines()[0]}" if twin.shutdown_message else ""
        raise Unusable(f"PID_CALIBRATE at {target} C did not finish in the twin: {error}{why}") from None
    return result.tu_s, result.peak_to_peak_c, (result.kp, result.ki, result.kd)


# --- tables (markdown) -------------------------------------------------------------------------


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "n/a" if x is None or not math.isfinite(x) else format(x, fmt)


def _pm(ok: bool) -> str:
    return "pass" if ok else "**miss**"


def open_loop_table(r: OpenLoopResult) -> str:
    v = r.fit.values
    lines = [(f"Fit ({r.fit.model}, ambient {ONION_AMBIENT_C} C, power held at {v['power_w']:g} W) on "
             f"`{ONION_NO_FAN}` {r.fit_segment}: RMSE {r.fit_rmse_c:.2f} C, max error {r.fit_max_err_c:.2f} C; "
             f"no-fan loss A = {v['ambient_xfer_w_k']:.4f} W/K, block C = {v['block_heat_capacity_j_k']:.2f} J/K, "
             f"sensor R = {v['sensor_responsiveness_per_s']:.4f} /s, cartridge G = {v['cartridge_xfer_w_k']:.4f} W/K."),
             "",
             ("| fan coefficient fitted on | predicted run (whole run) | predicted run starts | fan (declared) "
              "| fan loss F (W/K) | F/A | RMSE on fitted run (C) "
             "| RMSE (C) | max error (C) | peak log / twin (C) | goal RMSE <= 3 C |"),
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in r.rows:
        lines.append(f"| `{row['fitted_on']}` | `{row['predicted']}` | {row['start']} | {row['fan']:g} | "
                     f"{row['fan_xfer_w_k']:.4f} | "
                     f"{row['fan_xfer_w_k'] / row['no_fan_xfer_w_k']:.2f} | {row['fit_rmse_c']:.2f} | "
                     f"{row['rmse_c']:.2f} | {row['max_err_c']:.2f} | {row['peak_log_c']:.1f} / "
                     f"{row['peak_twin_c']:.1f} | {_pm(row['passed'])} |")
    p = r.later_pulse
    lines += ["", (f"The same fit on the no-fan log's second pulse (from {p['t_s']:.1f} s; no fan in either pulse): "
                   f"RMSE {p['rmse_after_c']:.2f} C with the state carried from the first pulse, "
                   f"{p['rmse_settled_c']:.2f} C from a settled start; peak log / twin "
                   f"{p['peak_log_c']:.1f} / {p['peak_twin_c']:.1f} C.")]
    return "\n".join(lines)


CLOSED_HEADER = ("| log | heater | fit segment | replayed heat-up | replay is | target (C) | heat-up to target-2 log / twin (s) "
                 "| error | overshoot log / twin (C) | hold RMSE twin-log (C) | steady pwm log / twin "
                 "| heat-up <= 10 % | overshoot <= 1.5 C | hold <= 1 C | notes |\n"
                 "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
CLOSED_COLUMNS = 15


def closed_loop_row(r: ClosedLoopResult) -> str:
    c = r.checks
    notes = []
    if r.same_segment:
        notes.append("only one heat-up: replayed the fitted one")
    if r.info.sensor_note:
        notes.append(r.info.sensor_note)
    if r.shutdown:
        notes.append(f"twin shut down: {r.shutdown}")
    if not _finite(r.twin.heatup_s):
        notes.append("twin never reaches target-2 C")
    sample = "in-sample" if r.same_segment else "held-out"
    return (f"| `{r.file}` | {r.heater} | {r.fit_label} | {r.replay_label} | {sample} | {r.target_c:g} | "
            f"{_f(r.log.heatup_s, '.1f')} / {_f(r.twin.heatup_s, '.1f')} | {_f(100 * r.heatup_rel, '+.1f')} % | "
            f"{_f(r.log.overshoot_c, '.1f')} / {_f(r.twin.overshoot_c, '.1f')} | {_f(r.hold_rmse_c)} | "
            f"{_f(r.log.steady_pwm, '.3f')} / {_f(r.twin.steady_pwm, '.3f')} | {_pm(c['heat-up'])} | "
            f"{_pm(c['overshoot'])} | {_pm(c['hold'])} | {'; '.join(notes)} |")


def _and(names: list[str]) -> str:
    return " and ".join(filter(None, (", ".join(names[:-1]), names[-1])))


def _misses(r: ClosedLoopResult) -> list[str]:
    return [name for name, ok in r.checks.items() if not ok]


def _replay_numbers(r: ClosedLoopResult) -> str:
    return (f"heat-up {_f(100 * r.heatup_rel, '+.1f')} %, overshoot {_f(r.log.overshoot_c, '.1f')} / "
            f"{_f(r.twin.overshoot_c, '.1f')} C, hold RMSE {_f(r.hold_rmse_c)} C")


def _hold_note(r: ClosedLoopResult) -> str:
    """The log's own hold about its target: above the hold goal, a twin at the target throughout misses."""
    twin = f" (twin {r.twin.hold_rms_c:.2f} C)" if _finite(r.twin.hold_rms_c) else ""
    note = f"the log's own hold RMS about its target is {_f(r.log.hold_rms_c)} C{twin}"
    if _finite(r.log.hold_rms_c) and r.log.hold_rms_c > GOAL_HOLD_RMSE_C:
        note += f", above the {GOAL_HOLD_RMSE_C:g} C goal: a twin holding the target exactly would miss it too"
    return note


def _settles_c(r: ClosedLoopResult) -> float:
    """Where the fitted plant settles at the heater's max_power (linear loss: ambient + rise x duty)."""
    return r.fit.values["ambient_c"] + r.info.max_power * r.fit.derived()["rise_at_full_power_c"]


def miss_note(e: MissEvidence) -> str:
    """One line of evidence for a replay that misses, every number computed (``miss_evidence``)."""
    r = e.result
    head = (f"`{r.file}` {r.heater}: the {'in-sample' if e.own is None else 'held-out'} replay of {r.replay_label} "
            f"misses {_and(_misses(r))}")
    if e.own is None:
        return (f"{head} ({r.fit.model} RMSE {r.fit.rmse_c:.2f} C on the heat-up itself; steady pwm "
                f"log / twin {_f(r.log.steady_pwm, '.3f')} / {_f(r.twin.steady_pwm, '.3f')} at max_power "
                f"{r.info.max_power:g}, where the fitted plant settles at {_settles_c(r):.1f} C); {_hold_note(r)}.")
    own_misses = _misses(e.own)
    if set(own_misses) >= set(_misses(r)):
        verdict = "the model misses this heat-up even fitted on it: its structure or the data, not the held-out fit"
    else:
        verdict = "fitted on this heat-up the model meets what the held-out fit misses: the heat-ups differ"
    return (f"{head}. Fitted on that heat-up itself ({e.own.fit_label}, RMSE {e.own.fit.rmse_c:.2f} C "
            f"against {r.fit.rmse_c:.2f} C for the held-out fit), its in-sample replay gives {_replay_numbers(e.own)} "
            f"({'misses ' + _and(own_misses) if own_misses else 'all three goals met'}): {verdict}. The two fits' "
            f"heating rates at full power {e.heating_rate_c_s[0]:.2f} / {e.heating_rate_c_s[1]:.2f} C/s "
            f"({_f(e.heating_rate_sigmas, '.1f')} standard errors apart), steady duty at {r.target_c:g} C "
            f"{e.hold_duty[0]:.3f} / {e.hold_duty[1]:.3f} (log {_f(r.log.steady_pwm, '.3f')}); {_hold_note(r)}.")


def unusable_row(file: str, heater: str, why: str, columns: int) -> str:
    return f"| `{file}` | {heater} | not usable: {why} |" + " |" * (columns - 3)


AUTOTUNE_HEADER = ("| log | heater | PID_CALIBRATE target (C) | Tu saved 2Kp/Ki (s) | Tu twin (s) | error "
                   "| peak-to-peak saved / twin (C) | twin gains Kp / Ki / Kd | goal Tu within 15 % "
                   "| band (C) | Tu twin at band ends (s) | within 15 % in the band |\n"
                   "|---|---|---|---|---|---|---|---|---|---|---|---|")
AUTOTUNE_COLUMNS = 12


def autotune_row(r: AutotuneResult) -> str:
    kp, ki, kd = r.twin_gains
    return (f"| `{r.file}` | {r.heater} | {r.target_c:g} (assumed) | {r.tu_log_s:.1f} | {r.tu_twin_s:.1f} | "
            f"{100 * r.tu_rel:+.1f} % | {r.p2p_log_c:.1f} / {r.p2p_twin_c:.1f} | {kp:.3f} / {ki:.3f} / {kd:.3f} | "
            f"{_pm(r.passed)} | {'..'.join(f'{t:g}' for t in CALIBRATION_BAND_C[r.heater])} | "
            f"{_f(r.tu_band_s[0], '.1f')} / {_f(r.tu_band_s[1], '.1f')} | {_pm(r.passed_in_band)} |")
