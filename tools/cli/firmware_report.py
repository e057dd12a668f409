"""`twin-firmware-report`: the firmware port's footprint and its measured error against the references.

Prints the thermistor table size and its interpolation error, the RAM each controller's state
takes on the ATmega328, and the worst difference between each integer controller and its float
reference on seeded random input sequences, next to the bound derived for it. Then, with the AVR
toolchain installed, each law's C compiled for the ATmega328P: flash and RAM from the ELF, peak
stack and cycles per call measured in simavr (firmware_port/avr/footprint.py), and the worst
call's share of one temperature-ISR period at 16 MHz. ``--doc docs/firmware.md`` rewrites that
table in the page. The numbers in docs/firmware.md come from this command.
"""

from __future__ import annotations

import argparse
import random
import sys
from pathlib import Path

from firmware_port.avr.footprint import CYCLES_PER_ISR, Footprint, measure_all
from firmware_port.avr.toolchain import AVR_CFLAGS, ToolchainMissing, find_toolchain

from firmware_port.fuzzy_pi import SEED004_BED, SEED004_HOTEND, FuzzyPi, FuzzyPiFloat, ram_report
from firmware_port.marlin.bangbang import BangBangBed
from firmware_port.marlin.pid import (
    PREV_TEMP_EVERY_SAMPLE,
    PREV_TEMP_IN_BAND,
    PidFixed,
    PidGains,
    float_error_bound_counts,
)
from firmware_port.marlin.pid_float import PidFloat
from firmware_port.thermistor import B3950_TABLE, TABLE_ERROR_BOUND_C, TEMP_ONE, Divider
from tools.cli.args import ranged_int, section_page, seed_int
from tools.entry import EXIT_STATUS_HELP, EXIT_USAGE, OneLineParser, run_main
from twin.limits import UserError

CALLS_MAX = 100_000  # --sequences, --steps: each law runs sequences x steps calls
# Gain sets to measure: Marlin's defaults and M303 results from the captured hardware logs.
PID_CASES = {
    "Marlin hotend default 22.20/1.08/114.00": PidGains(22.2, 1.08, 114.0),
    "Marlin bed default 10.00/0.023/305.40": PidGains(10.0, 0.023, 305.4),
    "Artillery hotend M303 10.45/1.15/23.72": PidGains(10.45, 1.15, 23.72),
    "Prusa MK3 bed M303 73.75/3.09/439.98": PidGains(73.75, 3.09, 439.98),
}


def table_report() -> list[str]:
    """Rows, flash and the worst interpolation error against the exact beta curve, 20..280 C."""
    divider = Divider()
    raw_hot, raw_cold = round(16 * divider.adc_exact(280.0)), round(16 * divider.adc_exact(20.0))
    worst = max(
        abs(B3950_TABLE.lookup_q5(raw) / TEMP_ONE - divider.temp_at_raw(raw)) for raw in range(raw_hot, raw_cold + 1)
    )
    return [
        f"B3950 table: {len(B3950_TABLE.raw)} rows, {B3950_TABLE.flash_bytes} bytes of flash",
        f"  worst lookup error vs beta curve, 20..280 C: {worst:.4f} C (bound {TABLE_ERROR_BOUND_C:.4f} C)",
    ]


def _walk(rng: random.Random, target_c: int, steps: int) -> list[int]:
    """A temperature sequence around a target, in celsius_q5: moves of up to 2 C a sample."""
    temp_q5 = (target_c + rng.randint(-15, 15)) * TEMP_ONE
    temps = []
    for _ in range(steps):
        temp_q5 += rng.randint(-64, 64)
        temps.append(temp_q5)
    return temps


def pid_report(rng: random.Random, sequences: int, steps: int) -> list[str]:
    """Worst |PidFixed - PidFloat| (counts of 0..255, before truncation) per gain set and mode."""
    lines = [
        f"PID fixed point: state {PidFixed.STATE_BYTES} bytes + gains {PidFixed.GAIN_BYTES} bytes per heater",
        f"  worst |fixed - float32| over {sequences} seeded sequences x {steps} samples:",
    ]
    for label, gains in PID_CASES.items():
        for mode in (PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND):
            worst, worst_int, max_dtemp_c = 0.0, 0, 0.0
            for _ in range(sequences):
                target_c = rng.randint(50, 250)
                temps = _walk(rng, target_c, steps)
                fixed, ref = PidFixed(gains, mode), PidFloat(gains, mode)
                for temp_q5 in temps:
                    if abs(target_c * TEMP_ONE - temp_q5) <= 10 * TEMP_ONE:  # in band: D sees this
                        max_dtemp_c = max(max_dtemp_c, abs(fixed.prev_q5 - temp_q5) / TEMP_ONE)
                    a = fixed.update_q8(temp_q5, target_c) / 256
                    b = float(ref.update_f32(temp_q5, target_c))
                    worst = max(worst, abs(a - b))
                    worst_int = max(worst_int, abs(int(a) - int(b)))
            bound = float_error_bound_counts(gains, max_dtemp_c)
            lines.append(
                f"    {label:40s} {mode}: {worst:.4f} counts (bound {bound:.4f}), integer output {worst_int}"
            )
    return lines


def fuzzy_report(rng: random.Random, sequences: int, steps: int) -> list[str]:
    """RAM of the fuzzy PI and its worst difference to the float oracle on random walks."""
    lines = []
    for label, config, target_c in (("hotend", SEED004_HOTEND, 214), ("bed", SEED004_BED, 105)):
        ram = ram_report(config)
        worst, worst_int = 0.0, 0
        for _ in range(sequences):
            fixed, ref = FuzzyPi(config), FuzzyPiFloat(config)
            for temp_q5 in _walk(rng, target_c, steps):
                out = fixed.update(temp_q5, target_c, 0)
                out_ref = ref.update(temp_q5, target_c, 0)
                worst = max(worst, abs(fixed.duty_q16 / 65536 - ref.duty))
                worst_int = max(worst_int, abs(out - out_ref))
        lines += [
            f"Fuzzy-like PI ({label}, n={config.n_sets}): state {ram['state_bytes']} bytes + "
            f"config {ram['config_bytes']} bytes, tables {ram['table_bytes']} bytes",
            f"  worst |integer - float| duty over {sequences} x {steps} samples: {worst:.4f} counts, "
            f"integer output {worst_int}",
        ]
    return lines


AVR_DOC_BEGIN = "<!-- avr-table: begin"
AVR_DOC_END = "<!-- avr-table: end -->"
AVR_COLUMNS = ("law", "flash B", "RAM B", "stack B", "cycles min / median / max", "max us", "ISR period",
               "CPU at its rate")


def avr_rows(footprints: list[Footprint]) -> list[tuple[str, ...]]:
    """One row of cells per law, in AVR_COLUMNS order."""
    return [(f.law, str(f.flash_bytes), str(f.ram_bytes), str(f.stack_bytes),
             f"{f.cycles_min} / {f.cycles_median:g} / {f.cycles_max}", f"{f.max_us:.1f}", f"{f.isr_share:.2%}",
             f"{f.cpu_share:.3%}") for f in footprints]


def avr_header(seed: int, sequences: int, steps: int) -> str:
    return (f"{find_toolchain().version}, {' '.join(AVR_CFLAGS)}; cycles in simavr at 16 MHz (one ISR period "
            f"{CYCLES_PER_ISR} cycles), seed {seed}, {sequences} sequences x {steps} calls per law (the thermistor: "
            "every raw value)")


def avr_report(footprints: list[Footprint], header: str) -> list[str]:
    widths = [max(len(cells[k]) for cells in [AVR_COLUMNS, *avr_rows(footprints)]) for k in range(len(AVR_COLUMNS))]
    lines = [f"AVR build ({header}):"]
    for cells in [AVR_COLUMNS, *avr_rows(footprints)]:
        lines.append("  " + "  ".join(c.ljust(w) if k == 0 else c.rjust(w) for k, (c, w) in enumerate(zip(cells, widths))))
    return lines


def avr_markdown(footprints: list[Footprint], header: str, command: str) -> str:
    """The table for docs/firmware.md, with the laws' titles and the command that wrote it."""
    lines = [f"Written by `{command}`: {header}.", "",
             "| " + " | ".join(AVR_COLUMNS) + " |", "|---|" + "---:|" * (len(AVR_COLUMNS) - 1)]
    for f, cells in zip(footprints, avr_rows(footprints)):
        lines.append(f"| {cells[0]}: {f.title} | " + " | ".join(cells[1:]) + " |")
    return "\n".join(lines) + "\n"


def read_doc(path: Path) -> str:
    """--doc's page, checked before any work: a UTF-8 text file we can write, with the table's markers."""
    try:
        return section_page(path, AVR_DOC_BEGIN, AVR_DOC_END)
    except ValueError as exc:
        raise UserError(f"--doc {path}: {exc}") from None


def write_avr_doc(path: Path, text: str, body: str) -> None:
    """The page's text (``read_doc``) with its AVR table replaced by ``body``, written back."""
    from tools.validation.doc_compare import replace_section

    path.write_text(str(replace_section(text, body, AVR_DOC_BEGIN, AVR_DOC_END)), encoding="utf-8")


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="twin-firmware-report", description=__doc__.splitlines()[0], epilog=EXIT_STATUS_HELP)
    parser.add_argument("--seed", type=seed_int, default=1,
                        help="seed of the random input sequences (default: %(default)s)")
    parser.add_argument("--sequences", type=ranged_int(1, CALLS_MAX), default=40,
                        help="sequences per case (default: %(default)s)")
    parser.add_argument("--steps", type=ranged_int(1, CALLS_MAX), default=300,
                        help="samples per sequence (default: %(default)s)")
    parser.add_argument("--doc", type=Path, help="rewrite the AVR table in this page (docs/firmware.md)")
    return parser


def run(args: argparse.Namespace, command: str) -> int:
    page = None
    if args.doc is not None:  # before any work: the build the table needs, and a page to write it in
        try:
            find_toolchain()
        except ToolchainMissing as exc:
            print(f"twin-firmware-report: --doc needs the AVR build: {exc}", file=sys.stderr)
            return EXIT_USAGE
        page = read_doc(args.doc)
    rng = random.Random(args.seed)
    lines = table_report()
    lines += pid_report(rng, args.sequences, args.steps)
    lines.append(f"Bang-bang: hotend 0 bytes, bed {BangBangBed.STATE_BYTES} byte of state")
    lines += fuzzy_report(rng, args.sequences, args.steps)
    try:
        footprints = measure_all(args.seed, args.sequences, args.steps)
        header = avr_header(args.seed, args.sequences, args.steps)
        lines += avr_report(footprints, header)
        if args.doc is not None and page is not None:
            write_avr_doc(args.doc, page, avr_markdown(footprints, header, command))
    except ToolchainMissing as exc:
        lines.append(f"AVR build: not measured: {exc}")
    print("\n".join(lines))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    command = " ".join(["twin-firmware-report", *(sys.argv[1:] if argv is None else argv)])
    return run_main(parser.prog, lambda: run(args, command))


if __name__ == "__main__":
    raise SystemExit(main())
