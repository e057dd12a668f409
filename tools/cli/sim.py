"""twin-sim: run a firmware build against the thermal plants through a scenario; print metrics.

With no arguments it heats the default hotend to 210 C (and the bed to 60 C) with Marlin's
fixed-point PID for 600 s of virtual time, prints the step metrics and writes the trace (CSV)
and a plot into ./twin-out/.
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import sys
import textwrap

from tqdm import tqdm

from firmware_port.firmwares import FIRMWARES
from firmware_port.marlin.mpc import MpcConstants, MpcController
from protocol.mpc_commands import hotend_mpc, mpc_constants_from_text
from tools.cli.args import check_output, ranged_float, ranged_int, seed_int
from twin.build import build_twin
from twin.clock import TICK_S
from twin.engine import ENGINES, TRACE_ROW_BYTES
from twin.limits import AMBIENT_RANGE_C, DURATION_MAX_S, INITIAL_RANGE_C, NOISE_MAX_LSB, TARGET_RANGE_C, UserError
from twin.plants import DEFAULT_BED, DEFAULT_HOTEND
from twin.plants import PRESETS as PLANT_PRESETS
from twin.scenario import PRESETS as SCENARIO_PRESETS
from twin.scenario import Scenario, ScenarioError, scenario_for, with_overrides
from tools.entry import INTERNAL_STATUS_HELP, OneLineParser, run_main

PROGRESS_STEP_S = 10.0  # virtual seconds between progress bar updates
ENGINE_NOTES = {"reference": "the tick-by-tick reference engine",
                "avr": "the controllers' C compiled for the ATmega328P, run in simavr"}  # said in the output
EXIT_HALTED = 1
EXIT_STATUS = """exit status:
  0  the run completed and no protection fault tripped
  1  the board halted: a thermal protection fault tripped (runaway, heating failed, MINTEMP,
     MAXTEMP); the trace and plot are written all the same
  2  bad input (an option, a scenario file, an output path), said in one line; nothing is run
""" + INTERNAL_STATUS_HELP


def build_parser() -> OneLineParser:
    parser = OneLineParser(
        prog="twin-sim",
        description=__doc__.splitlines()[0],
        epilog="\n\n".join([*(textwrap.fill(paragraph, 100) for paragraph in (
            "firmwares: " + "; ".join(f"{k}: {v[2]}" for k, v in FIRMWARES.items()) + ".",
            "plants: " + ", ".join(PLANT_PRESETS) + ". scenarios: " + ", ".join(SCENARIO_PRESETS) + ".",
            "outputs: OUT/<scenario>_<firmware>[_<what differs from the defaults>].csv and .png: a non-default "
            "engine, plant, --set, --no-bed or gains go into the name, so runs of other plants or gains do not overwrite "
            "each other. --out is created; --csv, --plot and --klipper-log must name a file in an existing folder.",
        )), EXIT_STATUS]),
    )
    parser.add_argument("--firmware", choices=list(FIRMWARES), default="pid", help="firmware build (default pid)")
    parser.add_argument("--plant", choices=list(PLANT_PRESETS), help=f"hotend plant preset (default: the scenario's, else {DEFAULT_HOTEND})")
    parser.add_argument("--bed-plant", choices=list(PLANT_PRESETS), help=f"bed plant preset (default: the scenario's, else {DEFAULT_BED})")
    parser.add_argument("--no-bed", action="store_true", help="a board with a hotend only")
    parser.add_argument("--scenario", default="heat_hold", help="preset name or TOML file (default heat_hold)")
    target, initial = ranged_int(*TARGET_RANGE_C), ranged_float(*INITIAL_RANGE_C, "C")
    parser.add_argument("--target", type=target, help="hotend target in C (replaces the scenario's first setpoint)")
    parser.add_argument("--bed-target", type=target, help="bed target in C")
    parser.add_argument("--duration", type=ranged_float(TICK_S, DURATION_MAX_S, "s"),
                        help="virtual seconds to run (default: the scenario's)")
    parser.add_argument("--ambient", type=ranged_float(*AMBIENT_RANGE_C, "C"), help="ambient temperature in C")
    parser.add_argument("--initial", type=initial, help="hotend starting temperature in C (default ambient)")
    parser.add_argument("--bed-initial", type=initial, help="bed starting temperature in C (default ambient)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="hotend plant parameter, e.g. --set power_w=50 (repeatable)")
    parser.add_argument("--bed-set", action="append", default=[], metavar="KEY=VALUE", help="bed plant parameter")
    parser.add_argument("--gains", metavar="KP,KI,KD", help="hotend PID gains at 0 s, M301 units (PID firmwares)")
    parser.add_argument("--bed-gains", metavar="KP,KI,KD", help="bed PID gains at 0 s, M304 units")
    parser.add_argument("--mpc-from", metavar="FILE|LINE",
                        help="MPC's model for --firmware mpc: an M306 line (as twin-fit, M306 or M503 print it) "
                             "or a file holding one; letters it leaves out keep Configuration.h's values")
    parser.add_argument("--seed", type=seed_int, help="seed of every random source (default: the scenario's, else 0)")
    parser.add_argument("--noise", type=ranged_float(0.0, NOISE_MAX_LSB, "LSB"), default=0.0,
                        help="ADC noise, standard deviation in LSB (default: %(default)s)")
    parser.add_argument("--engine", choices=ENGINES, default="fast", help="fast (default), the tick-by-tick reference, or avr: fast with the "
                        "controllers' C compiled for the ATmega328P and run in simavr (a non-default engine is said "
                        "in the output and its file names)")
    parser.add_argument("--record-every", type=ranged_float(0.0, DURATION_MAX_S, "s"), default=0.0, metavar="SECONDS",
                        help="at most one trace row per SECONDS (default: %(default)s, every firmware reading, 0.164 s; "
                             f"a row costs up to {TRACE_ROW_BYTES} bytes: bound long runs with this)")
    parser.add_argument("--out", default="twin-out",
                        help="directory for the default trace and plot, created if missing (default twin-out)")
    parser.add_argument("--csv", help="trace CSV path (default OUT/<run name>.csv, see outputs below)")
    parser.add_argument("--klipper-log", help="also write the trace as Klipper Stats lines to this path")
    parser.add_argument("--plot", help="plot PNG path (default OUT/<run name>.png; needs matplotlib)")
    parser.add_argument("--no-plot", action="store_true", help="do not draw a plot")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def parse_settings(items: list[str], option: str) -> dict[str, float | str]:
    """KEY=VALUE pairs; numbers become floats. ValueError names the bad item."""
    settings: dict[str, float | str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UserError(f"{option} {item!r}: expected KEY=VALUE")
        try:
            settings[key.strip()] = float(value)
        except ValueError:
            settings[key.strip()] = value.strip()
    return settings


def parse_gains(text: str | None, option: str) -> dict[str, float] | None:
    """"KP,KI,KD" -> {"kp", "ki", "kd"}; ValueError names the option."""
    if text is None:
        return None
    parts = text.split(",")
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) != 3:
        raise UserError(f"{option} {text!r}: expected three numbers KP,KI,KD")
    return dict(zip(("kp", "ki", "kd"), values, strict=True))


def read_mpc_constants(source: str) -> MpcConstants:
    """--mpc-from: the constants of the first M306 line of a file, or of the argument itself; every letter
    it gives must be a finite number, every constant positive (H may be 0)."""
    text = source
    if os.path.isfile(source):
        try:
            with open(source, encoding="utf-8", errors="replace") as handle:
                text = handle.read()
        except OSError as exc:
            raise UserError(f"--mpc-from {source!r}: {exc.strerror or exc}") from None
    try:
        return mpc_constants_from_text(text, strict=True)
    except ValueError as exc:
        raise UserError(f"--mpc-from {source!r}: {exc}") from None


def hotend_controllers(args: argparse.Namespace) -> list:
    """--mpc-from: the hotend's MPC with those constants, as a factory (a board reset rebuilds it)."""
    if args.mpc_from is None:
        return []
    if args.firmware != "mpc":
        raise UserError(f"--mpc-from sets MPC's model: it needs --firmware mpc, not {args.firmware}")
    return [functools.partial(MpcController, read_mpc_constants(args.mpc_from))]


def run_name(scenario_name: str, args: argparse.Namespace) -> str:
    """<scenario>_<firmware>, then what differs from the defaults (plants, --set, --no-bed, gains),
    so that a run of another plant or other gains does not overwrite this one's files."""
    parts = [scenario_name, args.firmware] + ([args.engine] if args.engine != "fast" else [])
    parts += [args.plant] if args.plant else []
    parts += [f"bed-{args.bed_plant}"] if args.bed_plant else []
    parts += ["nobed"] if args.no_bed else []
    parts += [item.replace("=", "-") for item in args.set] + [f"bed-{item.replace('=', '-')}" for item in args.bed_set]
    parts += [f"gains-{args.gains.replace(',', '-')}"] if args.gains else []
    parts += [f"bedgains-{args.bed_gains.replace(',', '-')}"] if args.bed_gains else []
    return re.sub(r"[^A-Za-z0-9._+-]", "_", "_".join(parts))


def check_outputs(out_dir: str, paths: list[tuple[str, str | None]], plot_path: str | None) -> None:
    """Before any work: the --out folder is made; every other output names a file we can write in an
    existing folder (as twin-compare asks of --plot, tools/cli/args.py check_output); the plot is a PNG."""
    if plot_path is not None and not plot_path.lower().endswith(".png"):
        raise UserError(f"--plot {plot_path!r}: the plot is written as PNG, give a .png path")
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create the output folder {out_dir!r}: {exc.strerror or exc}") from None
    for option, path in paths:
        if path is not None:
            try:
                check_output(path)
            except ValueError as exc:
                raise UserError(f"{option} {path!r}: {exc}") from None


def clamp_notes(twin, scenario) -> list[str]:
    """Setpoints the firmware clamps (Marlin: maxtemp - 15 hotend, - 10 bed), said out loud."""
    notes = []
    for event in scenario.events:
        channel = {"hotend": 0, "bed": 1}.get(str(event.heater))
        if event.kind != "target" or channel is None or channel >= len(twin.plants):
            continue
        top_c = twin.board.heaters[channel].temp_range.clamp_target(10_000)
        if int(event.value) > top_c:
            notes.append(f"note: {event.heater} target {event.value} C at {event.at_s:g} s is clamped to {top_c} C "
                         "by the firmware, as Marlin clamps M104/M140")
    return notes


def gains_line(twin) -> str:
    """The gains each heater runs with now (after the scenario's 0 s events)."""
    names = ("hotend", "bed")[: len(twin.plants)]
    parts = [f"{name} Kp {g.kp:g} Ki {g.ki:g} Kd {g.kd:g}" for channel, name in enumerate(names)
             if twin.board.has_gains(channel) for g in [twin.board.gains(channel)]]
    return "gains: " + ("; ".join(parts) if parts else "none (no PID in this firmware)")


def _scenario(args: argparse.Namespace) -> Scenario:
    """The scenario ``--scenario`` names with the command line's plants, targets, gains and other overrides."""
    scenario = scenario_for(args.scenario)
    plant = {heater: dict(params) for heater, params in scenario.plant.items()}
    for heater, preset, items, option in (
        ("hotend", args.plant, args.set, "--set"),
        ("bed", args.bed_plant, args.bed_set, "--bed-set"),
    ):
        params = plant.setdefault(heater, {})
        if preset:
            params["preset"] = preset
        params.update(parse_settings(items, option))
    targets = {k: v for k, v in (("hotend", args.target), ("bed", args.bed_target)) if v is not None}
    initial = {k: v for k, v in (("hotend", args.initial), ("bed", args.bed_initial)) if v is not None}
    gains = {k: v for k, v in (("hotend", parse_gains(args.gains, "--gains")),
                               ("bed", parse_gains(args.bed_gains, "--bed-gains"))) if v is not None}
    return with_overrides(
        scenario, duration_s=args.duration, ambient_c=args.ambient, initial_c=initial or None,
        targets=targets or None, seed=args.seed, plant=plant, gains=gains or None,
    )


def run(args: argparse.Namespace) -> int:
    scenario = _scenario(args)
    if args.record_every > scenario.duration_s:
        raise UserError(f"--record-every {args.record_every:g}: must be 0..duration_s ({scenario.duration_s:g}) seconds")
    stem = run_name(scenario.name, args)
    plot_path = None if args.no_plot else (args.plot or os.path.join(args.out, stem + ".png"))
    csv_path = args.csv or os.path.join(args.out, stem + ".csv")
    controllers = hotend_controllers(args)
    check_outputs(args.out, [("--csv", csv_path), ("--klipper-log", args.klipper_log), ("--plot", plot_path)],
                  plot_path)
    twin = build_twin(scenario, args.firmware, controllers=controllers, with_bed=not args.no_bed, engine=args.engine,
                      noise_lsb=args.noise)
    twin.record_every_s = args.record_every
    try:
        twin.check_horizon(scenario.duration_s)
    except ValueError as exc:
        raise UserError(f"--duration {scenario.duration_s:g}: {exc}") from None
    twin.run_until(0.0)  # the scenario's 0 s events: targets and gains in force
    engine = f", engine {args.engine} ({ENGINE_NOTES[args.engine]})" if args.engine in ENGINE_NOTES else ""
    print(f"twin-sim: {scenario.name}, firmware {args.firmware}, {scenario.duration_s:g} s virtual, "
          f"seed {scenario.seed or 0}{engine}")
    print(gains_line(twin))
    if (mpc := hotend_mpc(twin.board)) is not None:
        print(f"mpc: {mpc.constants.m306()}")
    for note in clamp_notes(twin, scenario):
        print(note)
    _run_with_progress(twin, scenario.duration_s)

    result = twin.result()
    print(result.report(_disturbances(scenario)))
    trips = result.protection_trips()
    for t, what, heater_id in trips:
        print(f"protection at {t:.1f} s: {what} on {heater_id}; the board halted (heaters off until reset)")

    _write(csv_path, result.to_csv())
    print(f"trace: {csv_path}")
    if args.klipper_log:
        _write(args.klipper_log, result.to_klipper_stats())
        print(f"klipper stats log: {args.klipper_log}")
    if plot_path is not None:
        try:
            os.makedirs(os.path.dirname(plot_path) or ".", exist_ok=True)
            engine_note = f" (engine {args.engine})" if args.engine != "fast" else ""
            result.plot(plot_path, f"{scenario.name}: {result.label}{engine_note}")
            print(f"plot: {plot_path}")
        except ImportError as exc:
            print(f"plot skipped: {exc}")
    return EXIT_HALTED if twin.board.halted else 0


def _disturbances(scenario) -> list[tuple[float, str]]:
    """The scenario's fan and flow changes, whose recovery the report measures."""
    return [(e.at_s, f"{e.kind} {e.value}") for e in scenario.events if e.kind in ("fan", "flow")]


def _run_with_progress(twin, duration_s: float) -> None:
    """Run in steps of virtual time, with a progress bar on stderr when it is a terminal."""
    with tqdm(total=duration_s, unit="s virtual", file=sys.stderr, disable=not sys.stderr.isatty(),
              bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s virtual [{elapsed}<{remaining}]") as bar:
        while twin.time_s < duration_s:
            twin.run_until(min(duration_s, twin.time_s + PROGRESS_STEP_S))
            bar.update(min(twin.time_s, duration_s) - bar.n)


def _write(path: str, text: str) -> None:
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from firmware_port.avr.laws import UnknownBuild  # light: numpy and the firmware port, no toolchain

    return run_main("twin-sim", lambda: run(args), errors=(ScenarioError, UserError, UnknownBuild))


if __name__ == "__main__":
    raise SystemExit(main())
