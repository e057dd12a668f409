"""twin-sim: run a firmware build against the thermal plants through a scenario; print metrics.

With no arguments it heats the default hotend to 210 C (and the bed to 60 C) with Marlin's
fixed-point PID for 600 s of virtual time, prints the step metrics and writes the trace (CSV)
and a plot into ./twin-out/.
"""

from __future__ import annotations

import argparse
import os
import sys

from firmware_port.firmwares import FIRMWARES
from twin.build import build_twin
from twin.engine import ENGINES
from twin.plants import PRESETS as PLANT_PRESETS
from twin.scenario import PRESETS as SCENARIO_PRESETS
from twin.scenario import ScenarioError, scenario_for, with_overrides

PROGRESS_SLICES = 20


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="twin-sim",
        description=__doc__.splitlines()[0],
        epilog=(
            "firmwares: " + "; ".join(f"{k}: {v[2]}" for k, v in FIRMWARES.items())
            + ". plants: " + ", ".join(PLANT_PRESETS) + ". scenarios: " + ", ".join(SCENARIO_PRESETS) + "."
        ),
    )
    parser.add_argument("--firmware", choices=list(FIRMWARES), default="pid", help="firmware build (default pid)")
    parser.add_argument("--plant", choices=list(PLANT_PRESETS), help="hotend plant preset (default: the scenario's, else hotend)")
    parser.add_argument("--bed-plant", choices=list(PLANT_PRESETS), help="bed plant preset (default: the scenario's, else bed)")
    parser.add_argument("--no-bed", action="store_true", help="a board with a hotend only")
    parser.add_argument("--scenario", default="heat_hold", help="preset name or TOML file (default heat_hold)")
    parser.add_argument("--target", type=int, help="hotend target in C (replaces the scenario's first setpoint)")
    parser.add_argument("--bed-target", type=int, help="bed target in C")
    parser.add_argument("--duration", type=float, help="virtual seconds to run (default: the scenario's)")
    parser.add_argument("--ambient", type=float, help="ambient temperature in C")
    parser.add_argument("--initial", type=float, help="hotend starting temperature in C (default ambient)")
    parser.add_argument("--bed-initial", type=float, help="bed starting temperature in C (default ambient)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="hotend plant parameter, e.g. --set power_w=50 (repeatable)")
    parser.add_argument("--bed-set", action="append", default=[], metavar="KEY=VALUE", help="bed plant parameter")
    parser.add_argument("--seed", type=int, help="seed of every random source (default: the scenario's, else 0)")
    parser.add_argument("--noise", type=float, default=0.0, help="ADC noise, standard deviation in LSB (default 0)")
    parser.add_argument("--engine", choices=ENGINES, default="fast", help="fast (default) or the tick-by-tick reference")
    parser.add_argument("--out", default="twin-out", help="directory for the default trace and plot (default twin-out)")
    parser.add_argument("--csv", help="trace CSV path (default OUT/<scenario>_<firmware>.csv)")
    parser.add_argument("--klipper-log", help="also write the trace as Klipper Stats lines to this path")
    parser.add_argument("--plot", help="plot PNG path (default OUT/<scenario>_<firmware>.png; needs matplotlib)")
    parser.add_argument("--no-plot", action="store_true", help="do not draw a plot")
    return parser.parse_args(argv)


def parse_settings(items: list[str], option: str) -> dict[str, float | str]:
    """KEY=VALUE pairs; numbers become floats. ValueError names the bad item."""
    settings: dict[str, float | str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{option} {item!r}: expected KEY=VALUE")
        try:
            settings[key.strip()] = float(value)
        except ValueError:
            settings[key.strip()] = value.strip()
    return settings


def run(args: argparse.Namespace) -> int:
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
    scenario = with_overrides(
        scenario, duration_s=args.duration, ambient_c=args.ambient, initial_c=initial or None,
        targets=targets or None, seed=args.seed, plant=plant,
    )
    twin = build_twin(scenario, args.firmware, with_bed=not args.no_bed, engine=args.engine, noise_lsb=args.noise)
    _run_with_progress(twin, scenario.duration_s)

    result = twin.result()
    print(f"twin-sim: {scenario.name}, firmware {args.firmware}, {scenario.duration_s:g} s virtual, seed {scenario.seed or 0}")
    print(result.report(_disturbances(scenario)))
    for t, what, heater_id in result.protection_trips():
        print(f"protection at {t:.1f} s: {what} on {heater_id}; the board halted (heaters off until reset)")

    stem = f"{scenario.name}_{args.firmware}".replace(" ", "_")
    csv_path = args.csv or os.path.join(args.out, stem + ".csv")
    _write(csv_path, result.to_csv())
    print(f"trace: {csv_path}")
    if args.klipper_log:
        _write(args.klipper_log, result.to_klipper_stats())
        print(f"klipper stats log: {args.klipper_log}")
    if not args.no_plot:
        plot_path = args.plot or os.path.join(args.out, stem + ".png")
        try:
            os.makedirs(os.path.dirname(plot_path) or ".", exist_ok=True)
            result.plot(plot_path, f"{scenario.name}: {result.label}")
            print(f"plot: {plot_path}")
        except ImportError as exc:
            print(f"plot skipped: {exc}")
    return 0


def _disturbances(scenario) -> list[tuple[float, str]]:
    """The scenario's fan and flow changes, whose recovery the report measures."""
    return [(e.at_s, f"{e.kind} {e.value}") for e in scenario.events if e.kind in ("fan", "flow")]


def _run_with_progress(twin, duration_s: float) -> None:
    """Run in slices, showing progress on a terminal."""
    show = sys.stderr.isatty()
    for k in range(1, PROGRESS_SLICES + 1):
        twin.run_until(duration_s * k / PROGRESS_SLICES)
        if show:
            print(f"\r  {100 * k // PROGRESS_SLICES:3d}% ({twin.time_s:.0f}/{duration_s:g} s virtual)", end="", file=sys.stderr)
    if show:
        print(file=sys.stderr)


def _write(path: str, text: str) -> None:
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(text)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        return run(args)
    except BrokenPipeError:  # `twin-sim | head`: the reader left, nothing more to say
        sys.stdout = None
        return 0
    except (ScenarioError, ValueError, OSError) as exc:
        print(f"twin-sim: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
