"""PID_CALIBRATE through the registry's klippy on the twin MCU against the twin's own port of it, on
the same plants: the table in docs/klipper.md.

For each plant preset, ``RUNS`` sessions of klippy 0.12.0.dev276 on twin-klipper-mcu at ``SPEED``
x real time (klippy under libfaketime) run ``PID_CALIBRATE HEATER=hotend TARGET=200`` from a cold
start; KlipperTwin runs the port's PID_CALIBRATE (KLIPPY_0_12's switches, the MCU's 10-bit ADC
and thermistor) on the same plant. ``python -m tools.docs.klipper_table --doc docs/klipper.md``
rewrites its section (needs the klippy venv and libfaketime: docs/klipper.md).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from tools.entry import OneLineParser, run_cli
from tools.klipper_host.calibration import BAND_SLACK_REL, band, parse_pid_reply, twin_pid_calibrate, within_band
from tools.klipper_host.session import KlipperSession
from tools.validation.doc_compare import publish_section

BEGIN, END = "<!-- klipper_table: begin", "<!-- klipper_table: end -->"
COMMAND = "python -m tools.docs.klipper_table --doc docs/klipper.md"
PLANTS = ("hotend_stock", "hotend", "hotend_cartridge")
TARGET_C = 200.0
RUNS = 2
SPEED = 10.0
TIMEOUT_S = 600.0  # one PID_CALIBRATE's wall time at SPEED, at most


def klippy_gains(plant: str, workdir: Path) -> tuple[float, float, float]:
    with KlipperSession(workdir, speed=SPEED, mcu_args=("--plant", plant, "--no-bed")) as session:
        return parse_pid_reply(session.api.gcode(f"PID_CALIBRATE HEATER=hotend TARGET={TARGET_C:g}", TIMEOUT_S))


def rows(plants: tuple[str, ...], runs: int) -> list[str]:
    lines = []
    for plant in plants:
        twin = twin_pid_calibrate(TARGET_C, plant)
        ranges = " / ".join(f"{low:.2f}-{high:.2f}" for low, high in band(twin))
        lines.append(f"| {plant} | twin port | {twin.kp:.3f} | {twin.ki:.3f} | {twin.kd:.3f} | {twin.tu_s:.1f} | "
                     f"{ranges} |")
        for run in range(runs):
            with tempfile.TemporaryDirectory(prefix="klipper_table") as workdir:
                got = klippy_gains(plant, Path(workdir))
            verdict = "in the band" if within_band(got, twin) else "OUT OF THE BAND"
            lines.append(f"| {plant} | klippy run {run + 1} | {got[0]:.3f} | {got[1]:.3f} | {got[2]:.3f} | "
                         f"{8 * got[2] / got[0]:.1f} | {verdict} |")
    return lines


def markdown(plants: tuple[str, ...], runs: int) -> str:
    head = [f"Written by `{COMMAND}`: `PID_CALIBRATE HEATER=hotend TARGET={TARGET_C:g}` from cold, {runs} runs of "
            f"klippy 0.12.0.dev276 on twin-klipper-mcu at {SPEED:g} x real time per plant, against the twin's "
            f"port (KlipperTwin, KLIPPY_0_12). Tu = 8 Kd / Kp. The band: Kp / Ki / Kd over the port's cycles "
            f"within one report of the median length, +-{100 * BAND_SLACK_REL:g} % (tools/klipper_host/calibration.py).",
            "", "| plant | by | pid_Kp | pid_Ki | pid_Kd | Tu s | band / verdict |", "|---|---|---|---|---|---|---|"]
    return "\n".join(head + rows(plants, runs)) + "\n"


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.klipper_table", description=__doc__.splitlines()[0])
    parser.add_argument("--doc", type=Path, help="rewrite the section of this file (docs/klipper.md)")
    parser.add_argument("--runs", type=int, default=RUNS, help="klippy runs per plant (default: %(default)s)")
    return parser


def run(args: argparse.Namespace) -> int:
    return publish_section(markdown(PLANTS, args.runs), args.doc, BEGIN, END)


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
