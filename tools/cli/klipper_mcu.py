"""twin-klipper-mcu: the twin as a Klipper MCU on a pseudo-terminal, for the user's own klippy.

Prints the port's path on stdout (the link's with --link), then the printer.cfg sections that
match the board (pins, thermistor type and pull-up, heaters, fan), then serves until Ctrl-C or
SIGTERM. Start klippy with that config (docs/klipper.md); FIRMWARE_RESTART resets the board.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import textwrap

from protocol.klipper_mcu.dictionary import DEFAULT_SENSOR, build_dictionary
from protocol.klipper_mcu.mcu import KlipperMcu
from protocol.klipper_mcu.server import McuServer
from protocol.klipper_mcu.user_config import ConfigError
from tools.cli.numbers import ranged_float
from tools.entry import OneLineParser, run_main
from twin.limits import UserError
from twin.scenario import ScenarioError

VERSION = "heater-twin-0.1.0"
LIBFAKETIME = "/usr/lib/x86_64-linux-gnu/faketime/libfaketimeMT.so.1"  # Debian's libfaketime package
MAX_SPEED = 50.0  # beyond this klippy cannot configure the MCU at all ("Timer too close" at 50x)
LENIENT_GRACE_S = 0.5  # lenient mode: wall seconds a late event may come after a missed max_duration

EXAMPLES = """examples:
  twin-klipper-mcu --link "$XDG_RUNTIME_DIR/twin-mcu" > printer.cfg   the port, then the config
  twin-klipper-mcu --speed 10 --link "$XDG_RUNTIME_DIR/twin-mcu"      10 x real time: klippy under libfaketime x10
  twin-klipper-mcu --scenario thermistor_falls_out                    the twin's faults, at the scenario's times
"""


def build_parser() -> OneLineParser:
    """The options; the plant and sensor names are checked after the twin is imported (``check_names``),
    so that --help and the port come before that import."""
    parser = OneLineParser(
        prog="twin-klipper-mcu", description=__doc__.split("\n\n")[0].replace("\n", " "),
        epilog=EXAMPLES + "\n" + textwrap.fill(
            "clock: the MCU's clock runs at --speed x real time. Above 1, start klippy under libfaketime at the "
            f"same factor (LD_PRELOAD={LIBFAKETIME} FAKETIME='+0 xS') so that its own timers (verify_heater, "
            "waits, idle timeout) keep pace; past about 10-20 x klippy cannot answer a reading in time. "
            "safety: a heater left on past its max_duration (klippy: 5 s) goes off then in every mode. "
            "--strict also shuts the MCU down then, and on an event the host scheduled too late ('Timer too "
            "close'), as a real MCU does; by default (lenient) a late event is applied as early as the plants "
            f"allow, one that comes within {LENIENT_GRACE_S:g} s of wall time after a missed max_duration is "
            "forgiven, none is the same shutdown; lateness is counted on stderr. The scenario's setpoints "
            "and gains are ignored: klippy sets them. plants: twin/plants.py's presets (a wrong name lists them).",
            width=100))
    parser.add_argument("--plant", metavar="NAME", help="hotend plant preset (default hotend_stock)")
    parser.add_argument("--bed-plant", metavar="NAME", help="bed plant preset (default bed)")
    parser.add_argument("--no-bed", action="store_true", help="a board with a hotend only")
    parser.add_argument("--scenario", metavar="NAME|FILE", help="scenario preset or TOML file: faults, ambient, "
                        "plant overrides, at world times from the MCU's start")
    parser.add_argument("--sensor-type", default=DEFAULT_SENSOR, metavar="NAME",
                        help=f"the thermistors on the board, a Klipper sensor_type the twin knows (default {DEFAULT_SENSOR}; "
                             "a wrong name lists them)")
    parser.add_argument("--noise-lsb", type=ranged_float(0.0, 100.0, "LSB"), default=0.0,
                        help="Gaussian noise of each ADC conversion in LSB (default %(default)s)")
    parser.add_argument("--speed", type=ranged_float(0.01, MAX_SPEED, "x real time"), default=1.0,
                        help="MCU clock speed, x real time (default %(default)s)")
    parser.add_argument("--strict", action="store_true", help="late host events shut the MCU down, as on a real one")
    parser.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pty (replaced if it is one)")
    parser.add_argument("--print-config", action="store_true", help="print the printer.cfg sections and exit")
    parser.add_argument("--printer-cfg", metavar="FILE", help="serve the board your printer.cfg's [mcu] is: its "
                        "chip's pins, heaters and thermistors on their pins, steppers and endstops on axes that "
                        "home; prints the config with [mcu] serial set to the port (docs/klipper.md)")
    parser.add_argument("--mcu", metavar="CHIP", help="the chip of --printer-cfg's [mcu] (default: what the config "
                        "says it is compiled for, else the smallest AVR with all its pins)")
    return parser


def check_names(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """argparse's own one-line error for a plant or sensor name the twin lacks (after its import)."""
    from firmware_port.thermistor import KLIPPER_SENSORS
    from twin.plants import PRESETS as PLANT_PRESETS

    for option, value, names in (("--plant", args.plant, PLANT_PRESETS), ("--bed-plant", args.bed_plant, PLANT_PRESETS),
                                 ("--sensor-type", args.sensor_type, KLIPPER_SENSORS)):
        if value is not None and value not in names:
            choices = ", ".join(repr(name) for name in names)
            parser.error(f"argument {option}: invalid choice: {value!r} (choose from {choices})")


def read_config(parser: argparse.ArgumentParser, args: argparse.Namespace):
    """--printer-cfg read (a one-line error if the twin cannot serve it), or None."""
    if args.printer_cfg is None:
        if args.mcu is not None:
            parser.error("argument --mcu: it names the chip of --printer-cfg, which is not given")
        return None
    from pathlib import Path

    from protocol.klipper_mcu.user_config import ConfigError, read_user_config

    try:
        return read_user_config(Path(args.printer_cfg), args.mcu)
    except ConfigError as exc:
        parser.error(f"argument --printer-cfg: {exc}")


def build_board(args: argparse.Namespace, config=None):
    """The twin's board (the heavy import: numpy, the plants, the thermistor tables)."""
    from protocol.build import serial_scenario
    from protocol.klipper_mcu.board import TwinBoard

    scenario = serial_scenario(args.scenario, args.plant, args.bed_plant)
    if config is not None:
        return TwinBoard.for_config(config, scenario, noise_lsb=args.noise_lsb)
    heaters = ("hotend",) if args.no_bed else ("hotend", "bed")
    return TwinBoard(scenario, heaters, sensor_type=args.sensor_type, noise_lsb=args.noise_lsb)


def served_config(address: str, board, config) -> str:
    """The printer.cfg to give klippy: the twin's sections, or the user's with [mcu] serial set to the port."""
    from protocol.klipper_mcu.printer_cfg import printer_cfg, user_printer_cfg

    return printer_cfg(address, board) if config is None else user_printer_cfg(config.path.read_text(), address)


def dictionary_for(config):
    from protocol.klipper_mcu.dictionary import BOARD_CHIP
    from protocol.klipper_mcu.mcu import PRINTER_FAMILIES

    if config is None:
        return build_dictionary(VERSION, BOARD_CHIP)
    return build_dictionary(VERSION, config.chip, families=PRINTER_FAMILIES)


def run(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    config = read_config(parser, args)
    if args.print_config:
        check_names(parser, args)
        print(served_config(args.link or "/tmp/twin-mcu", build_board(args, config), config))
        return 0
    sys.setswitchinterval(0.001)  # the reader thread stamps bytes within a millisecond of their arrival
    with McuServer(args.speed, link=args.link) as server:
        print(server.address, flush=True)  # before the twin's import: the port is there for klippy at once
        check_names(parser, args)
        board = build_board(args, config)
        dictionary = dictionary_for(config)
        grace_clocks = dictionary.chip.clocks(LENIENT_GRACE_S * args.speed)
        mcu = KlipperMcu(board, dictionary, strict=args.strict, grace_clocks=grace_clocks)
        print(served_config(server.address, board, config), flush=True)
        mode = "strict" if args.strict else "lenient"
        print(f"twin-klipper-mcu: {server.address}, speed {args.speed:g}, {mode} timing; Ctrl-C stops",
              file=sys.stderr, flush=True)
        try:
            server.serve_forever(mcu)
        finally:
            if not args.strict:
                print(f"twin-klipper-mcu: {mcu.lateness.line()}", file=sys.stderr, flush=True)
    return 0


def _stop(signum: int, frame) -> None:
    raise SystemExit(0)


def main(argv: list[str] | None = None) -> int:
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _stop)
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(format="twin-klipper-mcu: %(levelname)s: %(message)s", stream=sys.stderr)
    return run_main("twin-klipper-mcu", lambda: run(parser, args), errors=(ScenarioError, UserError, ConfigError))


if __name__ == "__main__":
    raise SystemExit(main())
