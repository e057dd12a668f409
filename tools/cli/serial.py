"""twin-serial: a virtual Marlin printer on a pseudo-terminal (or TCP port) for a real host.

Prints the port's path (with --tcp, HOST:PORT) on stdout, one line, then serves until Ctrl-C or
SIGTERM. Point Printrun, OctoPrint or pyserial at it, at any baud rate; opening the port resets
the board like a USB printer's DTR auto-reset. In-process, without a pty:
``import protocol; serial.serial_for_url("twin://?firmware=pid&speed=max")``.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import textwrap

from firmware_port.firmwares import FIRMWARES
from protocol.build import build_printer
from protocol.corruption import RxCorruptor
from protocol.pacing import MAX, Pacer, parse_idle_speed, parse_speed
from protocol.pty_server import PtyServer
from protocol.server import Server
from protocol.tcp_server import SECRET_LINE_MAX, TAKEOVER_AFTER_S, TcpServer
from protocol.transcript import Transcript
from tools.cli.args import output_file, ranged_float, ranged_int, seed_int
from tools.entry import EXIT_STATUS_HELP, OneLineParser, run_main
from twin.limits import UserError, check_regular_file
from twin.plants import PRESETS as PLANT_PRESETS
from twin.scenario import ScenarioError

DEFAULT_TCP_HOST = "127.0.0.1"
BAUD_MAX = 2**31 - 1  # termios's speed_t; any rate up to it is accepted (and ignored)


def _speed(text: str):
    try:
        return parse_speed(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _idle_speed(text: str) -> float:
    try:
        return parse_idle_speed(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


EXAMPLES = """examples:
  twin-serial --link /tmp/printer          OctoPrint or Pronterface: connect to /tmp/printer, any baud;
                                           M109/M303 finish in seconds, an idle printer runs in real time
  twin-serial --tcp 127.0.0.1:8250         pyserial socket://127.0.0.1:8250, or Pronterface's host:port
  twin-serial --tcp 0.0.0.0:8250 --secret-file key
                                           on the network: every client sends key's first line first
  twin-serial --idle-speed 10              idle heating and M155 reports at 10 x real time
  twin-serial --idle-speed 0 --log s.log   host-driven clock (stops while the host is idle): a session
                                           is a pure function of the bytes sent; transcript in s.log
  twin-serial --settings eeprom.json       M500 keeps the PID gains across runs
  twin-serial --corrupt-rx 0.05 --seed 3   a noisy wire: exercise the host's resend handling
"""


def _tcp_address(text: str) -> tuple[str, int]:
    """HOST:PORT, [IPv6]:PORT or :PORT (loopback); port 0 picks a free one."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or int(port) > 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, e.g. 127.0.0.1:8250, not {text!r}")
    return host.strip("[]") or DEFAULT_TCP_HOST, int(port)


def _secret(path: str) -> bytes:
    """The first line of FILE (only its first SECRET_LINE_MAX + 1 bytes are read); a FIFO or a device is
    refused before it is opened (opening a FIFO waits for a writer)."""
    try:
        check_regular_file(path)
        with open(path, "rb") as file:
            head = file.read(SECRET_LINE_MAX + 1)
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"cannot read {path}: {exc.strerror or exc}") from None
    except UserError as exc:
        raise argparse.ArgumentTypeError(f"{path}: {exc}") from None
    line = head.split(b"\n", 1)[0].rstrip(b"\r")
    if not line or len(line) > SECRET_LINE_MAX:
        raise argparse.ArgumentTypeError(f"the first line of {path} must hold the secret, 1 to {SECRET_LINE_MAX} bytes")
    return line


def build_parser() -> OneLineParser:
    parser = OneLineParser(
        prog="twin-serial",
        description=__doc__.split("\n\n")[0].replace("\n", " "),
        epilog=EXAMPLES + "\n" + textwrap.fill(
            "clock: while a command executes (M109, M190, M303, G4, M400, a G1 waiting for the planner) "
            "it runs at --speed: 'max' runs free, N at N x real time. While the printer waits for the host "
            "it runs at --idle-speed x real time, so M104 heats and M155 reports arrive; 0 stops it there "
            "(host-driven). M155 reports and busy keepalives come at most once per interval of wall time "
            "as well. firmwares: " + ", ".join(FIRMWARES) + ". plants: " + ", ".join(PLANT_PRESETS) + ". "
            "--log writes one line per chunk: DIR VIRTUAL_S WALL_S DATA, DIR '>' host to printer, "
            "'<' printer to host, '*' connect/reset/corruption; DATA a Python literal. "
            "--corrupt-rx flips, in that fraction of the host's lines, one random bit of one random byte "
            "(the end of line included) before the printer reads it: Marlin's checksum and line-number "
            "checks answer with Resend. A flipped end of line leaves the line open until the host sends "
            "more, and a line number flipped to the last one is dropped silently: a host that waits for "
            "'ok' without a timeout stalls there, as on a real printer.", width=100) + "\n\n" + EXIT_STATUS_HELP,
    )
    parser.add_argument("--firmware", choices=list(FIRMWARES), default="pid", help="firmware build (default pid)")
    parser.add_argument("--plant", choices=list(PLANT_PRESETS), help="hotend plant preset (default hotend)")
    parser.add_argument("--bed-plant", choices=list(PLANT_PRESETS), help="bed plant preset (default bed)")
    parser.add_argument("--no-bed", action="store_true", help="a board with a hotend only")
    parser.add_argument("--scenario", metavar="NAME|FILE",
                        help="scenario preset or TOML file for faults, ambient and plant overrides "
                             "(default: none; the host sets every target)")
    parser.add_argument("--speed", type=_speed, default=MAX, metavar="{1,N,max}",
                        help="clock speed while a command executes (default max: free)")
    parser.add_argument("--idle-speed", type=_idle_speed, metavar="N",
                        help="clock speed while the printer waits for the host, x real time; 0: stopped, "
                             "the host-driven clock (default 1 with --speed max, else the --speed N)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--link", metavar="PATH",
                       help="also make PATH a symlink to the pty (replaced if it is one; removed on exit)")
    where.add_argument("--tcp", type=_tcp_address, metavar="HOST:PORT",
                       help="serve on TCP instead of a pty, one client at a time (port 0: any free port); "
                            "an address other than loopback needs --secret-file or --allow-remote")
    parser.add_argument("--secret-file", type=_secret, metavar="FILE", dest="secret",
                        help="--tcp: every client must send FILE's first line as its own first line; one that "
                             "does takes the printer over at once (docs/serial.md, Connections)")
    parser.add_argument("--allow-remote", action="store_true",
                        help="--tcp: listen beyond loopback without a secret (anyone who reaches the port can "
                             "drive the printer)")
    parser.add_argument("--takeover-after", type=ranged_float(1.0, 86400.0, "s"), default=TAKEOVER_AFTER_S,
                        metavar="S", help="--tcp without a secret: a new client takes the printer over only once the "
                                          "current one has left it waiting S wall seconds (default %(default)s)")
    parser.add_argument("--settings", metavar="FILE", help="EEPROM file that M500 writes and M501 reads; "
                        "an existing file must be one M500 wrote (default: in memory, lost on exit)")
    parser.add_argument("--keep-corrupt-settings", action="store_true",
                        help="a --settings file that does not load (CRC or version mismatch) stops twin-serial "
                             "at start and is left as it is (default: the defaults load, as Marlin's do, and the "
                             "next M500 replaces it)")
    parser.add_argument("--log", metavar="FILE", type=output_file,
                        help="transcript of both directions with virtual and wall times")
    parser.add_argument("--no-ok-after-resend", dest="ok_after_resend", action="store_false",
                        help="no 'ok' after 'Resend:' (a buggy firmware, to test a host's handling; "
                             "default: 'ok' follows, as GCodeQueue::flush_and_request_resend() sends in Marlin 2.1)")
    parser.add_argument("--corrupt-rx", type=ranged_float(0.0, 1.0, ""), default=0.0, metavar="P",
                        help="probability per received line of one flipped bit (default: %(default)s, a clean wire)")
    parser.add_argument("--seed", type=seed_int, default=0, metavar="N",
                        help="seed of --corrupt-rx's draws: a host sending the same lines gets the same "
                             "flips (default 0)")
    parser.add_argument("--baud", type=ranged_int(1, BAUD_MAX), metavar="N",
                        help="accepted and ignored: any baud rate works")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    return build_parser().parse_args(argv)


def run(args: argparse.Namespace) -> int:
    printer = build_printer(
        firmware=args.firmware, plant=args.plant, bed_plant=args.bed_plant, with_bed=not args.no_bed,
        scenario=args.scenario, settings=args.settings, ok_after_resend=args.ok_after_resend,
        keep_corrupt_settings=args.keep_corrupt_settings,
    )
    transcript = Transcript(args.log) if args.log else None
    corruptor = RxCorruptor(args.corrupt_rx, args.seed) if args.corrupt_rx else None
    pacer = Pacer(printer, args.speed, args.idle_speed)
    try:
        server: Server
        if args.tcp:
            host, port = args.tcp
            try:
                server = TcpServer(printer, pacer, host, port, transcript=transcript, corruptor=corruptor,
                                   secret=args.secret, allow_remote=args.allow_remote,
                                   takeover_after_s=args.takeover_after)
            except OSError as exc:
                raise OSError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        else:
            server = PtyServer(printer, pacer, link=args.link, transcript=transcript, corruptor=corruptor)
        with server:
            print(server.address, flush=True)
            link = f" (link {args.link})" if args.link else ""
            noise = f", rx corruption {args.corrupt_rx:g} (seed {args.seed})" if corruptor else ""
            idle = f"idle {pacer.idle_speed:g}" if pacer.idle_speed else "idle clock stopped (host-driven)"
            print(f"twin-serial: {server.address}{link}, firmware {args.firmware}, speed {args.speed}, {idle}{noise}; "
                  "Ctrl-C stops", file=sys.stderr, flush=True)
            server.serve_forever()
    finally:
        if transcript is not None:
            transcript.close()
    return 0


def _stop(signum: int, frame) -> None:
    raise SystemExit(0)  # unwinds through the server's context manager: link removed, fds closed


def main(argv: list[str] | None = None) -> int:
    for signum in (signal.SIGINT, signal.SIGTERM):  # SIGINT too: a background job starts with it ignored
        signal.signal(signum, _stop)
    args = parse_args(argv)
    logging.basicConfig(format="twin-serial: %(levelname)s: %(message)s", stream=sys.stderr)
    return run_main("twin-serial", lambda: run(args), errors=(ScenarioError, UserError))


if __name__ == "__main__":
    raise SystemExit(main())
