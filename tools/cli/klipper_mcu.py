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

from firmware_port.thermistor import KLIPPER_SENSORS
from protocol.build import serial_scenario
from protocol.klipper_mcu.board import DEFAULT_SENSOR, TwinBoard
from protocol.klipper_mcu.dictionary import build_dictionary
from protocol.klipper_mcu.mcu import KlipperMcu
from protocol.klipper_mcu.printer_cfg import printer_cfg
from protocol.klipper_mcu.server import McuServer
from tools.cli.args import ranged_float
from tools.entry import OneLineParser, run_main
from twin.limits import UserError
from twin.plants import PRESETS as PLANT_PRESETS
from twin.scenario import ScenarioError

VERSION = "heater-twin-0.1.0"
LIBFAKETIME = "/usr/lib/x86_64-linux-gnu/faketime/libfaketimeMT.so.1"  # Debian's libfaketime package
MAX_SPEED = 50.0  # beyond this klippy cannot configure the MCU at all ("Timer too close" at 50x)

EXAMPLES = """examples:
  twin-klipper-mcu --link /tmp/twin-mcu > printer.cfg    the port, then the config; klippy: serial /tmp/twin-mcu
  twin-klipper-mcu --speed 10 --link /tmp/twin-mcu       10 x real time: run klippy under libfaketime at x10
  twin-klipper-mcu --scenario thermistor_falls_out       the twin's faults, at the scenario's times
"""


def build_parser() -> OneLineParser:
    parser = OneLineParser(
        prog="twin-klipper-mcu", description=__doc__.split("\n\n")[0].replace("\n", " "),
        epilog=EXAMPLES + "\n" + textwrap.fill(
            "clock: the MCU's clock runs at --speed x real time. Above 1, start klippy under libfaketime at the "
            f"same factor (LD_PRELOAD={LIBFAKETIME} FAKETIME='+0 xS') so that its own timers (verify_heater, "
            "waits, idle timeout) keep pace; past about 10-20 x klippy cannot answer a reading in time. "
            "--strict shuts the MCU down on an event the host scheduled too late ('Timer too close') or a "
            "heater left without a next value past max_duration, as a real MCU does; by default such "
            "lateness is counted and the event applied as early as the plants allow. The scenario's setpoints "
            "and gains are ignored: klippy sets them. plants: " + ", ".join(PLANT_PRESETS) + ".", width=100))
    parser.add_argument("--plant", choices=list(PLANT_PRESETS), help="hotend plant preset (default hotend_stock)")
    parser.add_argument("--bed-plant", choices=list(PLANT_PRESETS), help="bed plant preset (default bed)")
    parser.add_argument("--no-bed", action="store_true", help="a board with a hotend only")
    parser.add_argument("--scenario", metavar="NAME|FILE", help="scenario preset or TOML file: faults, ambient, "
                        "plant overrides, at world times from the MCU's start")
    parser.add_argument("--sensor-type", choices=list(KLIPPER_SENSORS), default=DEFAULT_SENSOR, metavar="NAME",
                        help=f"the thermistors on the board, a Klipper sensor_type: {', '.join(KLIPPER_SENSORS)} "
                             f"(default {DEFAULT_SENSOR})")
    parser.add_argument("--noise-lsb", type=ranged_float(0.0, 100.0, "LSB"), default=0.0,
                        help="Gaussian noise of each ADC conversion in LSB (default %(default)s)")
    parser.add_argument("--speed", type=ranged_float(0.01, MAX_SPEED, "x real time"), default=1.0,
                        help="MCU clock speed, x real time (default %(default)s)")
    parser.add_argument("--strict", action="store_true", help="late host events shut the MCU down, as on a real one")
    parser.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pty (replaced if it is one)")
    parser.add_argument("--print-config", action="store_true", help="print the printer.cfg sections and exit")
    return parser


def build_board(args: argparse.Namespace) -> TwinBoard:
    scenario = serial_scenario(args.scenario, args.plant, args.bed_plant)
    heaters = ("hotend",) if args.no_bed else ("hotend", "bed")
    return TwinBoard(scenario, heaters, sensor_type=args.sensor_type, noise_lsb=args.noise_lsb)


def run(args: argparse.Namespace) -> int:
    board = build_board(args)
    if args.print_config:
        print(printer_cfg(args.link or "/tmp/twin-mcu", board))
        return 0
    mcu = KlipperMcu(board, build_dictionary(VERSION), strict=args.strict)
    with McuServer(mcu, args.speed, link=args.link) as server:
        print(server.address, flush=True)
        print(printer_cfg(server.address, board), flush=True)
        mode = "strict" if args.strict else "lenient"
        print(f"twin-klipper-mcu: {server.address}, speed {args.speed:g}, {mode} timing; Ctrl-C stops",
              file=sys.stderr, flush=True)
        server.serve_forever()
    return 0


def _stop(signum: int, frame) -> None:
    raise SystemExit(0)


def main(argv: list[str] | None = None) -> int:
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _stop)
    args = build_parser().parse_args(argv)
    logging.basicConfig(format="twin-klipper-mcu: %(levelname)s: %(message)s", stream=sys.stderr)
    return run_main("twin-klipper-mcu", lambda: run(args), errors=(ScenarioError, UserError))


if __name__ == "__main__":
    raise SystemExit(main())
