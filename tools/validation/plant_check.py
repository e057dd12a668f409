"""`python -m tools.validation.plant_check`: the plant presets against real hardware logs.

Runs the presets open loop as the logs were recorded, through the twin's own plant API (runs of
ticks between the logs' sample instants), and prints the log's numbers next to the model's:
- hotend, hotend_cartridge: the onionheater no-fan pulse test (hardware_logs README section B):
  heating rate near 100 C, overshoot after cut-off and its time, RMSE over the pulse and its
  cooling; hotend_cartridge also on the other pulse runs, with the log's own heater input;
- bed: the chesleavens Klipper Stats heat-up (README section A); bed_mk3: seed 004's numbers.
``--fit`` reruns the least-squares fits (tools/ident/fit.py, and the MK3 solve) whose results
twin/plants.py holds. The logs are read by tools/logs/ from $HEATER_TWIN_HARDWARE_LOGS (default:
<repo>/../shared/hardware_logs).
The numbers in docs/plants.md come from this command.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np
import scipy.optimize

from tools.ident.fit import fit_losses, fit_model, fit_plants
from tools.ident.response import zoh_response
from tools.ident.result import FitResult, aic
from tools.ident.segments import Segment
from tools.logs import csv_rows, parse_heattest, parse_klipper_stats_csv
from tools.logs import hardware_logs_dir as logs_dir
from twin.linear import SENSOR, TICK_S
from twin.plants import MK3_POWER_W, SPECS, Lumped, Plant, make_plant
from tools.entry import OneLineParser, run_cli

# Onionheater pulse tests (README section B; the author's notes in the files' headers).
ONION_LOG = "klipper_heattest_onionheater_{}.csv"
ONION_AMBIENT_C = 21.4  # "room 21.4 C"
ONION_CUT_C = 200.5  # the first pulse of heattest_200 was cut at this reading
ONION_RATE_BAND_C = (88.0, 116.0)  # "full power heats ~2.0 C/s between 88 and 116 C"
ONION_PULSE_END_S = 722.0  # heattest_200: the second pulse starts at 722.61 s
ONION_FIT_FIXED = ("power_w", "cartridge_heat_capacity_j_k")
ONION_CARTRIDGE_PROFILE_J_K = (1.0, 4.0, 8.0)  # the fit is flat in the cartridge's capacity: shown by refits
ONION_FIT_START = {"block_heat_capacity_j_k": 16.7, "cartridge_xfer_w_k": 1.0,  # MPC defaults, a 1 W/K contact
                   "sensor_responsiveness_per_s": 0.22, "ambient_xfer_w_k": 0.068}
# and, fitting the radiation-like loss too, tools/ident/fit.py's RADIATING_START_M2 within RADIATING_BOUNDS_M2

# Chesleavens bed (README section A): session 0, heat-up to 65 C, hold, step down to 60 C.
BED_LOG = "klippy_stats_chesleavens_cartesian_stm32f103.csv"
BED_AMBIENT_C = 25.2  # the bed's reading before the heat-up
BED_WINDOW_S = 660.0  # from the heater's first line: heat-up, 65 C, step down into the 60 C hold
BED_RATE_BAND_C = (30.0, 45.0)  # pwm 1.0 throughout
BED_FIT_START = {"block_heat_capacity_j_k": 500.0, "sensor_responsiveness_per_s": 0.2, "ambient_xfer_w_k": 2.0}

# Seed 004's MK3 bed: duty capped at 220/255, "about 10 minutes to reach 100 C".
MK3_DUTY = 220 / 255
MK3_AMBIENT_C = 25.0  # not stated
MK3_TIME_TO_100_S = 600.0


def read_log(name: str) -> dict[str, np.ndarray]:
    """A hardware-log CSV as columns of floats, read (and checked) by tools/logs/; empty cells are NaN."""
    _, rows = csv_rows(logs_dir() / name)
    (_, header), data = rows[0], rows[1:]
    return {h: np.array([float(r[i]) if r[i] else np.nan for _, r in data]) for i, h in enumerate(header)}


def replay(plant, t_s: np.ndarray, pwm: np.ndarray | None = None, cut_c: float | None = None) -> np.ndarray:
    """The plant's sensor at the instants t_s (from t_s[0]), its heater at the log's pwm (held from
    each instant to the next) or, without pwm, at full power until the sensor reads cut_c."""
    if pwm is not None:
        return zoh_response(plant, t_s, pwm)
    ticks = np.rint((t_s - t_s[0]) / TICK_S).astype(int)
    out = np.empty(len(t_s))
    out[0] = plant.temps_c()[SENSOR]
    u = 1.0
    for i, n in enumerate(np.diff(ticks)):
        plant.advance(np.full(n, u))
        plant.relinearise()
        out[i + 1] = plant.temps_c()[SENSOR]
        if out[i + 1] >= cut_c:
            u = 0.0
    return out


def _crossing_s(t_s: np.ndarray, temp_c: np.ndarray, level_c: float) -> float:
    """First time temp_c reaches level_c, interpolated between samples."""
    i = int(np.argmax(temp_c >= level_c))
    return float(np.interp(level_c, temp_c[i - 1 : i + 1], t_s[i - 1 : i + 1]))


def rate_c_s(t_s: np.ndarray, temp_c: np.ndarray, band_c: tuple[float, float]) -> float:
    low, high = band_c
    return (high - low) / (_crossing_s(t_s, temp_c, high) - _crossing_s(t_s, temp_c, low))


def pulse_numbers(t_s: np.ndarray, temp_c: np.ndarray, cut_c: float) -> dict[str, float]:
    """Heating rate, time on, and the overshoot after the first reading >= cut_c (heater cut there)."""
    cut = int(np.argmax(temp_c >= cut_c))
    peak = cut + int(np.argmax(temp_c[cut:]))
    return {
        "rate": rate_c_s(t_s, temp_c, ONION_RATE_BAND_C),
        "time_on": t_s[cut] - t_s[0],
        "peak": temp_c[peak],
        "overshoot": temp_c[peak] - temp_c[cut],
        "peak_after": t_s[peak] - t_s[cut],
    }


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def onion_run(name: str, fan: float = 0.0, t_min_s: float = 0.0, t_max_s: float = np.inf) -> Segment:
    """An onionheater run from the last sample before its first heater-on sample at or after t_min_s
    (the reading the heater started from; at 0.25 C resolution the first heated one can be a step
    up already), up to t_max_s."""
    log = parse_heattest(logs_dir() / ONION_LOG.format(name))
    t_s, pwm = log.t_s, log.pwm
    first = max(int(np.argmax((pwm > 0) & (t_s >= t_min_s))) - 1, 0)
    keep = (t_s >= t_s[first]) & (t_s < t_max_s)
    return Segment(name, t_s[keep], log.temp_c[keep], pwm[keep], fan)


def onion_runs() -> list[tuple[str, Segment]]:
    """The first no-fan pulse (the fit's data) and the runs that check it, with a note each."""
    return [
        ("no fan, first pulse (fit)", onion_run("heattest_200", t_max_s=ONION_PULSE_END_S)),
        ("no fan, second pulse", onion_run("heattest_200", t_min_s=ONION_PULSE_END_S)),
        ("no fan, author's trace", onion_run("sample_trace")),
        ("part fan on (fan fit)", onion_run("heattest_fan_200", fan=1.0)),
        ("part fan on (fan fit)", onion_run("heattest_fan_200_2", fan=1.0)),
    ]


def onion_plant(run: Segment, preset: str = "hotend_cartridge", **params):
    """A hotend preset at the onionheater's ambient, every node at the run's first reading, its fan set."""
    plant = make_plant(preset, ambient_c=ONION_AMBIENT_C, initial_c=run.temp_c[0], **params)
    plant.set_inputs(fan=run.fan, flow_mm_s=0.0, ambient_c=ONION_AMBIENT_C)
    return plant


def hotend_report() -> list[str]:
    """Both hotend presets on the first no-fan pulse, cut at 200.5 C by their own sensor."""
    run = onion_run("heattest_200", t_max_s=ONION_PULSE_END_S)
    rows: dict[str, tuple[dict[str, float], np.ndarray | None]] = {
        "log": (pulse_numbers(run.t_s, run.temp_c, ONION_CUT_C), None)}
    for preset in ("hotend", "hotend_cartridge"):
        model_c = replay(onion_plant(run, preset), run.t_s, cut_c=ONION_CUT_C)
        rows[preset] = (pulse_numbers(run.t_s, model_c, ONION_CUT_C), model_c - run.temp_c)
    lines = [
        f"Hotend: onionheater no-fan pulse ({ONION_LOG.format(run.label)}, {run.t_s[0]:.2f}..{run.t_s[-1]:.2f} s)",
        f"  open loop: ambient {ONION_AMBIENT_C} C, every node at the log's first reading {run.temp_c[0]:.2f} C,",
        f"  full power until the sensor reads >= {ONION_CUT_C} C at a sample instant (0.3 s), then off",
        f"  {'':36}" + "".join(f"{name:>18}" for name in rows),
    ]
    for key, label, fmt in (
        ("rate", f"heating rate {ONION_RATE_BAND_C[0]:.0f}->{ONION_RATE_BAND_C[1]:.0f} C, C/s", "{:.2f}"),
        ("time_on", "time on until the cut, s", "{:.1f}"),
        ("peak", "peak after cut-off, C", "{:.2f}"),
        ("overshoot", "overshoot over the cut reading, C", "{:.2f}"),
        ("peak_after", "time of the peak after the cut, s", "{:.1f}"),
    ):
        lines.append(f"  {label:36}" + "".join(f"{fmt.format(numbers[key]):>18}" for numbers, _ in rows.values()))
    for label, stat in (("RMSE over the run, C", rms), ("max |error| over the run, C", lambda e: np.max(np.abs(e)))):
        errors = [err for _, err in rows.values() if err is not None]
        lines.append(f"  {label:36}{'-':>18}" + "".join(f"{stat(err):>18.2f}" for err in errors))
    lines.append("  hotend_cartridge with each run's logged heater input (ambient 21.4 C, fan runs at fan = 1):")
    for note, run in onion_runs():
        err = replay(onion_plant(run), run.t_s, run.duty) - run.temp_c
        loss_name = "fan_ambient_xfer_w_k" if run.fan else "ambient_xfer_w_k"
        loss = fit_plants(onion_plant, {loss_name: 0.09}, [run]).values
        lines.append(f"    {run.label:19}{run.t_s[0]:7.1f}..{run.t_s[-1]:6.1f} s  RMSE {rms(err):5.2f} C"
                     f"  max {np.max(np.abs(err)):5.2f} C  {loss_name} alone: {loss[loss_name]:.4f} W/K  {note}")
    return lines


def bed_run() -> Segment:
    """The chesleavens bed heat-up window: its first session, from the heater's first line."""
    bed = parse_klipper_stats_csv(logs_dir() / BED_LOG).sessions[0]["heater_bed"]
    start_s = bed.t_s[np.argmax(bed.pwm > 0)]
    keep = (bed.t_s >= start_s) & (bed.t_s <= start_s + BED_WINDOW_S)
    return Segment("chesleavens bed", bed.t_s[keep], bed.temp_c[keep], bed.pwm[keep])


def bed_plant(run: Segment, **params):
    return make_plant("bed", ambient_c=BED_AMBIENT_C, initial_c=run.temp_c[0], **params)


def steady_duty(plant, temp_c: float) -> float:
    """Duty that holds a fan-less lumped plant at temp_c: its loss over its power."""
    return plant.spec.ambient_xfer_w_k * (temp_c - plant.ambient_c) / plant.spec.power_w


def heat_up(plant, duty: float = 1.0, limit_s: float = 3600.0) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, sensor temp_c) at a constant duty, every 0.5 s."""
    t_s = np.arange(0.0, limit_s, 0.5)
    return t_s, replay(plant, t_s, np.full(len(t_s), duty))


def bed_report() -> list[str]:
    run, log = bed_run(), read_log(BED_LOG)  # the CSV's own session numbers label the holds
    err = replay(bed_plant(run), run.t_s, run.duty) - run.temp_c
    full_t_s, full_c = heat_up(bed_plant(run), limit_s=600.0)
    rate = BED_RATE_BAND_C
    lines = [
        f"Bed: chesleavens ({BED_LOG}, session 0,",
        f"  {BED_WINDOW_S:.0f} s from the heater's first line), ambient {BED_AMBIENT_C} C",
        f"  {'':56}{'log':>10}{'bed':>10}",
        f"  {f'heating rate {rate[0]:.0f}->{rate[1]:.0f} C at full power, C/s':56}"
        f"{rate_c_s(run.t_s, run.temp_c, rate):10.3f}{rate_c_s(full_t_s, full_c, rate):10.3f}",
        f"  {f'time {run.temp_c[0]:.1f} -> 65 C, s (log: PID, full power to ~56 C)':56}"
        f"{_crossing_s(run.t_s - run.t_s[0], run.temp_c, 65.0):10.0f}{_crossing_s(full_t_s, full_c, 65.0):10.0f}",
    ]
    plant = bed_plant(run)
    for session in (0, 2):
        for target_c in (60, 65):
            rows = ((log["session"] == session) & (log["heater_bed_target"] == target_c)
                    & (np.abs(log["heater_bed_temp"] - target_c) < 0.5))
            label = f"mean duty within 0.5 C of {target_c} C (session {session}, {rows.sum()} lines)"
            logged = np.mean(log["heater_bed_pwm"][rows])
            lines.append(f"  {label:56}{logged:10.3f}{steady_duty(plant, target_c):10.3f}")
    lines.append(f"  {'RMSE with the logged pwm over the window, C':56}{'-':>10}{rms(err):10.2f}")
    lines.append(f"  {'max |error|, C':56}{'-':>10}{np.max(np.abs(err)):10.2f}")
    mk3 = make_plant("bed_mk3", ambient_c=MK3_AMBIENT_C)
    assert isinstance(mk3.spec, Lumped)
    t_s, temp_c = heat_up(mk3, MK3_DUTY)
    lines += [
        f"Bed MK3 (seed 004): ambient {MK3_AMBIENT_C} C (assumed), duty 220/255 = {MK3_DUTY:.3f}",
        f"  time to 100 C: paper about {MK3_TIME_TO_100_S:.0f} s, bed_mk3 {_crossing_s(t_s, temp_c, 100.0):.0f} s",
        f"  duty to hold 105 C: bed_mk3 {steady_duty(mk3, 105.0):.3f} (the paper held 104 C under the 0.863 cap);"
        f" highest reachable at the cap {MK3_AMBIENT_C + MK3_DUTY * MK3_POWER_W / mk3.spec.ambient_xfer_w_k:.1f} C",
    ]
    return lines


def onion_fit_options(**fixed: float) -> dict:
    """fit_model's arguments for the no-fan first pulse: three_node at the onionheater's ambient, every
    node at the run's first reading, power_w and the cartridge's capacity as in hotend_cartridge (or
    as ``fixed``), from ONION_FIT_START."""
    first = onion_runs()[0][1]
    preset = {name: getattr(SPECS["hotend_cartridge"], name) for name in ONION_FIT_FIXED}
    return {"model": "three_node", "t_s": first.t_s, "temp_c": first.temp_c, "duty": first.duty,
            "ambient_c": ONION_AMBIENT_C, "fixed": {**preset, "initial_c": float(first.temp_c[0]), **fixed},
            "start": ONION_FIT_START}


def _preset_params(fit: FitResult) -> dict[str, float]:
    """A fit's values as hotend_cartridge's parameters: the fitted ones and the emissivity."""
    return {**fit.params, "emissivity": fit.values.get("emissivity", 0.0)}


def _onion_maker(fixed: dict[str, float]) -> Callable[..., Plant]:
    """hotend_cartridge with these parameters and, per run, the fitted ones (fit_plants' maker)."""
    def make(run: Segment, **fitted: float) -> Plant:
        return onion_plant(run, "hotend_cartridge", **{**fixed, **fitted})
    return make


def _fit_lines(name: str, fit: FitResult, held_out: Segment) -> list[str]:
    """A fit's values +- standard errors, RMSE, AIC, and its RMSE on the held-out run."""
    params = _preset_params(fit)
    err = zoh_response(onion_plant(held_out, "hotend_cartridge", **params), held_out.t_s, held_out.duty) - held_out.temp_c
    return ([f"  {name} (emissivity {params['emissivity']:g}):"]
            + [f"    {k} = {v:.4g} +- {fit.std_errors[k]:.2g}" for k, v in fit.params.items()]
            + [f"    RMSE {fit.rmse_c:.2f} C, AIC {aic(fit):.0f}; held out ({held_out.label}): RMSE {rms(err):.2f} C"])


def fit_report() -> list[str]:
    """The least-squares fits behind hotend_cartridge (and ONION_RADIATING_PARAMS) and bed, and the MK3 loss solve."""
    runs = [run for _, run in onion_runs()]
    fits, chosen = fit_losses(**onion_fit_options())
    profile = {capacity: fit_model(**onion_fit_options(cartridge_heat_capacity_j_k=capacity)).rmse_c
               for capacity in ONION_CARTRIDGE_PROFILE_J_K}
    fan_runs = [run for run in runs if run.fan]
    fan_fits = {name: fit_plants(_onion_maker(_preset_params(fit)), {"fan_ambient_xfer_w_k": 0.09}, fan_runs)
                for name, fit in fits.items()}
    bed_fit = fit_plants(bed_plant, BED_FIT_START, [bed_run()])
    bed, bed_rms = bed_fit.values, bed_fit.rmse_c

    def mk3_error_s(loss_w_k: float) -> float:
        t_s, temp_c = heat_up(make_plant("bed_mk3", ambient_c=MK3_AMBIENT_C, ambient_xfer_w_k=loss_w_k,
                                         fan_ambient_xfer_w_k=loss_w_k), MK3_DUTY)
        return _crossing_s(t_s, temp_c, 100.0) - MK3_TIME_TO_100_S

    mk3_loss = scipy.optimize.brentq(mk3_error_s, 0.3, 1.0, xtol=1e-5)
    return (
        [f"hotend_cartridge ({', '.join(ONION_FIT_FIXED)} as in the preset): heattest_200 first pulse,",
         f"  from {ONION_FIT_START}"]
        + [line for name, fit in fits.items() for line in _fit_lines(name, fit, runs[2])]
        + [f"  lower AIC: {chosen} (hotend_cartridge holds the linear fit, ONION_RADIATING_PARAMS the other)"]
        + ["  linear RMSE refitted with another cartridge_heat_capacity_j_k: "
           + ", ".join(f"{capacity:g} J/K {rmse:.2f} C" for capacity, rmse in profile.items())]
        + ["  then fan_ambient_xfer_w_k on both fan runs at fan = 1: " + ", ".join(
            f"{name} {fit.values['fan_ambient_xfer_w_k']:.4g} (RMSE {fit.rmse_c:.2f} C)" for name, fit in fan_fits.items())]
        + [f"bed (power_w as in the preset): chesleavens session 0 heat-up, from {BED_FIT_START}"]
        + [f"  {name} = {value:.4g}" for name, value in bed.items()] + [f"  RMSE {bed_rms:.2f} C"]
        + [f"bed_mk3: ambient_xfer_w_k = {mk3_loss:.4f} (100 C at {MK3_TIME_TO_100_S:.0f} s, duty 220/255)"]
    )


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.validation.plant_check", description=__doc__.splitlines()[0])
    parser.add_argument("--fit", action="store_true", help="rerun the fits whose results twin/plants.py holds")
    return parser


def run(args: argparse.Namespace) -> int:
    print(f"hardware logs: {logs_dir()}")
    print("\n".join(fit_report() if args.fit else hotend_report() + bed_report()))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
