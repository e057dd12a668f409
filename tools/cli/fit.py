"""twin-fit: fit a thermal model to a heater log; print its parameters and ready-to-paste settings.

LOG is any log tools/logs/ reads (Klipper Stats CSV or klippy.log, Klipper heattest, Marlin
M303 console text with status reports, a plain t,temp,duty CSV). The log's segments worth fitting
are listed (tools/ident/fit.py log_segments: heat-ups with their hold, pulses, status runs); one is
fitted (--segment, default the first with at least half the longest time at full power). The
output gives each parameter with its standard error, the residuals, a FOPDT equivalent, and
Marlin (M306 for two_node, M301/M304) and Klipper settings (PID gains by the AMIGO rule).
--loss radiating or auto adds a radiation-like loss to two_node/three_node (docs/plants.md).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from tools.cli.args import OneLineParser, ranged_float
from tools.ident.relay_trace import AMBIENT_PRIOR_C, ambient_hint_c
from tools.ident.fit import LOSSES, LUMPED_MODELS, MODELS, RADIATING_BOUNDS_M2, RADIATING_EMISSIVITY, RADIATING_PARAM, fit_losses, fit_model
from tools.ident.fopdt import CONTROL_DELAY_S, Fopdt, fopdt_equivalent, relay_fopdt, ultimate_point
from tools.ident.result import FitResult, aic
from tools.ident.segments import NotFittable, Segment, default_segment, log_segments
from tools.tuning.rules import amigo
from tools.logs import MARLIN_POWER_MAX, HeattestLog, LogError, M303Log, PlainLog, StatsLog, load_log
from twin.plants import BED_POWER_W, MPC_HEATER_POWER_W

BED = "heater_bed"
HEATER_NAMES = ("extruder", BED)  # the heaters a log here can hold
MARLIN_KU_SCALE = 255.0  # M303 prints Ku = 4 d / (pi a) with the relay's half swing d on 0..255
ASSUMED_POWER_W = {BED: BED_POWER_W}  # else MPC_HEATER_POWER_W; twin/plants.py says where both come from
KINDS = {StatsLog: "Klipper Stats", HeattestLog: "Klipper heattest (open loop)", M303Log: "Marlin M303 console text",
         PlainLog: "plain CSV (time, temperature, duty)"}
STATS_NOTE = ("Klipper Stats: pwm is the last value sent to the MCU, once a second; Klipper holds back a change "
              "under 5 % of max_power for up to 2.1..3.75 s (by version). It is the input all the same.")
ERRORS_NOTE = ("standard errors: from the Jacobian, for independent residuals; a log's residuals are correlated "
               "(model error, quantised readings), so take them as lower bounds")


EXAMPLES = """examples:
  twin-fit klippy.log                                   the extruder's heat-up, two_node (gives M306)
  twin-fit klippy.log --heater heater_bed --power-w 250 the bed, with its real wattage
  twin-fit heattest.csv --model three_node --ambient 21.4
  twin-fit m303_capture.txt --ambient 24                an M303 console capture (relay trace)
  twin-fit m303_bed.txt --heater heater_bed             a capture without its M303 E-1 line
  twin-fit heattest.csv --model three_node --loss auto  with a radiation-like loss too, if AIC prefers it
"""
AMBIENT_RANGE_C = (-40.0, 100.0)  # a room, a heated enclosure: a wider value is a typo
POWER_RANGE_W = (0.1, 5000.0)  # a 0.1 W test heater to a mains bed


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = OneLineParser(prog="twin-fit", description=__doc__, epilog=EXAMPLES)
    parser.add_argument("log", metavar="LOG", help="the log file")
    parser.add_argument("--model", choices=MODELS,
                        help="two_node (Marlin's MPC model, gives M306; the default), three_node (plus the heater "
                             "cartridge: the default for an M303 capture, whose relay period needs the lag), fopdt or "
                             "sopdt (first/second order plus dead time)")
    parser.add_argument("--heater", choices=HEATER_NAMES,
                        help="extruder or heater_bed (default: extruder, or the log's only heater; for an M303 "
                             "capture without its M303 line, which heater it tuned)")
    parser.add_argument("--session", type=int, help="only this session of a Klipper log (0-based, as listed)")
    parser.add_argument("--segment", type=int, help="the segment to fit (as listed; default: the first with at "
                        "least half the longest time at full power)")
    parser.add_argument("--ambient", type=ranged_float(*AMBIENT_RANGE_C, "C"),
                        help="ambient temperature in C (default: fitted, at most the segment's lowest reading; for "
                             "an M303 capture, whose readings all sit near the target, the idle bed's reading or "
                             f"{AMBIENT_PRIOR_C:g} C)")
    parser.add_argument("--power-w", type=ranged_float(*POWER_RANGE_W, "W"),
                        help="heater power in W for two_node/three_node (default: assumed "
                        f"{MPC_HEATER_POWER_W:g} W for a hotend, {BED_POWER_W:g} W for a bed)")
    parser.add_argument("--loss", choices=LOSSES, default="linear",
                        help="two_node/three_node heat loss: linear (the default, Marlin's MPC model), radiating "
                             "(plus sigma area (T^4 - Ta^4), an effective area at emissivity 1 fitted within "
                             f"{RADIATING_BOUNDS_M2[0] * 1e4:g}..{RADIATING_BOUNDS_M2[1] * 1e4:g} cm^2) or auto "
                             "(both, the lower AIC kept)")
    args = parser.parse_args(argv)
    if args.loss != "linear" and args.model not in (None, *LUMPED_MODELS):
        parser.error(f"--loss {args.loss} needs --model two_node or three_node: {args.model} has no heat-loss term")
    return args


def _param_lines(result: FitResult) -> list[str]:
    lines = []
    for name, value in result.params.items():
        error = result.std_errors[name]
        spread = ("at its bound" if np.isnan(error) else "not determined by this segment" if np.isinf(error)
                  else f"+- {error:.2g}")
        lines.append(f"  {name:30} {value:12.5g}  {spread}")
    lines += [f"  {name:30} {value:12.5g}  held" for name, value in result.fixed.items()]
    return lines


def _settings_lines(result: FitResult, heater: str, sample_s: float) -> list[str]:
    """The FOPDT equivalent, its ultimate point and the settings to paste; tuned on a dead time of
    at least the log's sample interval (a log cannot show a shorter one)."""
    fopdt = fopdt_equivalent(result)
    how = "the fit itself" if result.model == "fopdt" else "seed 001's two-point method on the model's step response"
    lines = [f"FOPDT equivalent ({how}): gain {fopdt.gain_c:.4g} C at full power, time constant "
             f"{fopdt.time_constant_s:.4g} s, dead time {fopdt.delay_s:.3g} s"]
    if fopdt.delay_s < sample_s:
        fopdt = fopdt._replace(delay_s=sample_s)
        lines.append(f"  tuned on a dead time of {sample_s:.3g} s, the log's sample interval: it cannot show less")
    delayed = fopdt._replace(delay_s=fopdt.delay_s + CONTROL_DELAY_S)
    ku, tu_s = ultimate_point(delayed)
    gains = amigo(delayed)
    kp, ki, kd = gains.kp, gains.ki, gains.kd
    lines += [f"  with the loop's {CONTROL_DELAY_S:g} s of delay: ultimate gain Ku {ku:.4g} duty per C (x255: Marlin's "
              f"M303 Ku), period Tu {tu_s:.4g} s: what an ideal relay test would find",
              "ready to paste (PID by the AMIGO rule on that FOPDT, gains on the 0..255 scale):"]
    v = result.values
    if heater == BED:
        lines.append(f"  Marlin:  M304 P{kp:.4g} I{ki:.4g} D{kd:.4g}   (Marlin's MPC, M306, is for hotends only)")
    else:
        if result.model == "two_node" and result.loss == "radiating":
            lines.append("  Marlin:  (M306 has no radiation term: --loss linear fits Marlin's MPC model)")
        elif result.model == "two_node":
            lines.append(f"  Marlin:  M306 P{v['power_w']:.2f} C{v['block_heat_capacity_j_k']:.2f} "
                         f"R{v['sensor_responsiveness_per_s']:.4f} A{v['ambient_xfer_w_k']:.4f} "
                         f"F{v['ambient_xfer_w_k']:.4f}")
            lines.append("           (P as assumed: with your heater's P', scale C, A and F by P'/P; F = A, the log "
                         "has no part-fan speed)")
        else:
            lines.append("  Marlin:  (M306 needs --model two_node: Marlin's MPC is that two-node model)")
        lines.append(f"           M301 P{kp:.4g} I{ki:.4g} D{kd:.4g}")
    lines += ["  Klipper:", f"    [{heater}]", "    control: pid", f"    pid_Kp: {kp:.4g}", f"    pid_Ki: {ki:.4g}",
              f"    pid_Kd: {kd:.4g}"]
    return lines


def _fit(model: str, seg: Segment, ambient_c: float | None, power_w: float | None,
         loss: str) -> tuple[FitResult, list[str]]:
    """The fit --loss asks for; for auto also the line comparing both losses."""
    series = (model, seg.t_s, seg.temp_c, seg.duty, ambient_c)
    if loss != "auto":
        return fit_model(*series, power_w=power_w, observed=seg.observed, loss=loss), []
    choice = fit_losses(*series, power_w=power_w, observed=seg.observed)
    compared = "; ".join(f"{name} RMSE {fit.rmse_c:.2f} C, AIC {aic(fit):.0f}" for name, fit in choice.fits.items())
    return choice.fits[choice.kept], [f"loss (--loss auto): {compared}: kept {choice.kept} (lower AIC)"]


def _radiation_line(result: FitResult) -> str:
    """The fitted radiating area in cm^2 with its standard error, and what it stands for."""
    area_cm2 = result.params[RADIATING_PARAM] * 1e4
    error = result.std_errors[RADIATING_PARAM] * 1e4
    spread = "at its bound" if np.isnan(error) else "not determined" if np.isinf(error) else f"+- {error:.2g} cm^2"
    return (f"  radiation: effective area {area_cm2:.4g} cm^2 {spread}, at emissivity {RADIATING_EMISSIVITY:g} "
            "(stands for every loss that grows faster than linearly with temperature)")


def run(args: argparse.Namespace) -> int:
    log = load_log(args.log)
    heater, segments = log_segments(log, args.heater, args.session)
    chosen = default_segment(segments) if args.segment is None else args.segment
    if not 0 <= chosen < len(segments):
        raise ValueError(f"--segment {chosen}: the segments are 0..{len(segments) - 1}")
    print(f"twin-fit: {args.log}")
    print(f"{KINDS.get(type(log), type(log).__name__)}; heater {heater}; segments (open loop: full power or off;"
          " in between: the controller's duty):")
    for i, seg in enumerate(segments):
        print(f"  {'*' if i == chosen else ' '}{i:3d}  {seg.label}, {len(seg.t_s)} samples: {seg.note}")
    seg = segments[chosen]
    model = args.model or ("three_node" if isinstance(log, M303Log) else "two_node")
    power_w = args.power_w
    if model in ("two_node", "three_node") and power_w is None:
        power_w = ASSUMED_POWER_W.get(heater, MPC_HEATER_POWER_W)
    ambient_c = args.ambient
    if ambient_c is None and isinstance(log, M303Log):
        ambient_c = ambient_hint_c(log)
        print(f"ambient {ambient_c:g} C: {'the idle heater reads it' if log.idle_readings_c else 'a room, assumed'}"
              " (a relay trace near its target cannot tell; --ambient sets it)")
    result, compared = _fit(model, seg, ambient_c, power_w, args.loss)
    for line in compared:
        print(line)
    print(f"fit: {model}{', radiating loss' if result.loss == 'radiating' else ''} on segment {chosen}"
          + (f", power_w {power_w:g} W assumed (the log fixes P/C and P/A, not the wattage)"
             if args.power_w is None and power_w else ""))
    print("\n".join(_param_lines(result) + ([_radiation_line(result)] if result.loss == "radiating" else [])))
    print(f"  RMSE {result.rmse_c:.2f} C, max |residual| {result.max_abs_residual_c:.2f} C"
          f" over {result.n_samples} samples")
    if derived := result.derived():
        print("  power-free: " + ", ".join(f"{name} {value:.4g}" for name, value in derived.items()))
    print(f"  {ERRORS_NOTE}")
    if isinstance(log, StatsLog):
        print(STATS_NOTE)
    print("\n".join(_settings_lines(result, heater, float(np.median(np.diff(seg.t_s))))))
    if isinstance(log, StatsLog) and (config := log.meta["config"].get(heater, {})).get("pid_kp"):
        print(f"the log's own gains: pid_Kp {config['pid_kp']}, pid_Ki {config.get('pid_ki')}, "
              f"pid_Kd {config.get('pid_kd')}")
    cycle = next((c for c in reversed(log.cycles) if c.ku and c.tu_s), None) if isinstance(log, M303Log) else None
    if cycle and log.power_max == MARLIN_POWER_MAX:  # Repetier's Ku takes the full swing: not compared
        print(_relay_line(cycle.ku / MARLIN_KU_SCALE, cycle.tu_s, fopdt_equivalent(result)))
    return 0


def _relay_line(ku: float, tu_s: float, fitted: Fopdt) -> str:
    """The log's own relay result as a FOPDT through the fitted gain, next to the fitted FOPDT."""
    try:
        relay = relay_fopdt(ku, tu_s, fitted.gain_c)
    except ValueError as exc:
        return f"the log's last relay cycle, Ku {ku:.4g} Tu {tu_s:.4g} s: {exc}"
    return (f"the log's last relay cycle, Ku {ku:.4g} duty per C, Tu {tu_s:.4g} s, through the fitted gain: time "
            f"constant {relay.time_constant_s:.4g} s, dead time {relay.delay_s:.3g} s (relay_fopdt; the fit: "
            f"{fitted.time_constant_s:.4g} s, {fitted.delay_s:.3g} s)")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        return run(args)
    except BrokenPipeError:  # `twin-fit LOG | head`: the reader left
        sys.stdout = None
        return 0
    except LogError as exc:
        print(f"twin-fit: error: {exc}", file=sys.stderr)
    except NotFittable as exc:
        print(f"twin-fit: error: {args.log}: not usable for fitting: {exc}", file=sys.stderr)
    except OSError as exc:
        print(f"twin-fit: error: {args.log}: {exc.strerror or exc}", file=sys.stderr)
    except ValueError as exc:
        print(f"twin-fit: error: {args.log}: {exc}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
