"""twin-compare LOG [--plot FILE]: the twin against one hardware log (tools/validation/compare.py,
tools/validation/m303_compare.py); every row says whether it is in-sample (the data the plant was
fitted to) or out-of-sample (data the plant never saw), and the summary counts out-of-sample rows only.

A Klipper Stats log: the closed-loop replay of a heat-up (held-out where the log has another one to
fit) and the PID_CALIBRATE cross-check for each heater. A Marlin M303 capture: a plant fitted to it
(its printed cycles and status trace) runs the twin's M303 at the same target; Tu and swing, twin
against log; --fit-cycles K fits the first K printed cycles only and predicts the rest, --plant
takes a preset or a plant fitted to another log instead. An onionheater heattest (with its sibling
runs in the same folder): the open-loop fan prediction. Tables fit in 120 columns; --plot writes
logged vs twin with matplotlib. A log that no check can use: one message on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

from tools.cli.args import plot_path, ranged_float
from tools.plots import compare_figure
from tools.plots.compare_figure import Trace
from tools.entry import EXIT_STATUS_HELP, OneLineParser, run_main
from tools.cli.progress import load_with_progress, progress_bar
from tools.ident.lsq import MAX_EVALUATIONS
from tools.ident.segments import NotFittable
from tools.logs import Log, LogError, StatsLog, heattest, klipper_stats, m303
from tools.validation import compare, m303_compare
from tools.validation.tables import WIDTH, markdown_cells, text_tables
from twin.limits import AMBIENT_RANGE_C, UserError



@dataclass
class Report:
    """What a check prints, what it plots, and its out-of-sample verdicts (the summary counts these)."""

    lines: list[str] = field(default_factory=list)
    traces: list[Trace] = field(default_factory=list)
    out_of_sample: list[bool] = field(default_factory=list)

    def table(self, header: str, rows: list[str], keys: int = 1) -> None:
        """A markdown table of tools/validation/compare.py as terminal text, without its log column."""
        columns = markdown_cells(header.splitlines()[0])
        self.lines += text_tables(columns, [markdown_cells(r) for r in rows], keys=keys, drop=("log",))

    def summary(self) -> str:
        n, ok = len(self.out_of_sample), sum(self.out_of_sample)
        if not n:
            return "summary: no out-of-sample row (in-sample rows are listed, not counted)"
        return f"summary: {ok}/{n} out-of-sample rows within their goals (in-sample rows are listed, not counted)"


# --- Klipper Stats -------------------------------------------------------------------------------


def _stats_heater(path: Path, heater: str, report: Report, closed: list[str], tunes: list[str]) -> None:
    """One heater's closed-loop replay and PID_CALIBRATE cross-check."""
    try:
        r = compare.closed_loop_check(path, heater)
    except (compare.Unusable, NotFittable) as error:
        closed.append(compare.unusable_row(path.name, heater, str(error), compare.CLOSED_COLUMNS))
        return
    closed.append(compare.closed_loop_row(r))
    fitted = "this heat-up (in-sample)" if r.same_segment else "another heat-up (held-out)"
    trip = None if r.shutdown is None or r.shutdown_s is None else (r.shutdown_s, r.shutdown.splitlines()[0])
    report.traces.append(Trace(f"{r.heater}: the twin replays the log's heat-up ({r.replay_label}) on the plant "
                               f"fitted to {fitted}", *r.trace, trip=trip))
    if not r.same_segment:
        report.out_of_sample.append(all(r.checks.values()))
    try:
        t = compare.autotune_check(path, heater, fit=r.fit)
    except (compare.Unusable, ValueError) as error:
        tunes.append(compare.unusable_row(path.name, heater, str(error), compare.AUTOTUNE_COLUMNS))
        return
    tunes.append(compare.autotune_row(t))
    report.out_of_sample.append(t.passed)


def _stats(args: argparse.Namespace, log: Log) -> Report:
    report, closed, tunes = Report(), list[str](), list[str]()
    for heater in compare.HEATERS:
        if any(heater in s for s in cast(StatsLog, log).sessions):  # what the Klipper Stats readers return
            _stats_heater(args.log, heater, report, closed, tunes)
    if not report.traces:
        raise compare.Unusable("no heater of this Klipper log has a heat-up to replay")
    report.lines += ["Closed-loop replay (held-out: the plant fitted to another heat-up; in-sample: to this one)", ""]
    report.table(compare.CLOSED_HEADER, closed)
    report.lines += ["", "PID_CALIBRATE cross-check (out-of-sample: the log's saved calibration against the twin's)",
                     ""]
    report.table(compare.AUTOTUNE_HEADER, tunes)
    return report


# --- heattests -------------------------------------------------------------------------------------


def _heattest(args: argparse.Namespace, log: Log) -> Report:
    path: Path = args.log
    if path.name not in compare.ONION_FILES or not all((path.parent / f).is_file() for f in compare.ONION_FILES[:3]):
        raise compare.Unusable("the open-loop check needs the onionheater no-fan and fan heattests side by side "
                               f"({', '.join(compare.ONION_FILES[:3])}); this heattest is not one of them")
    r = compare.open_loop_check(path.parent)
    report = Report(["Open-loop prediction (onionheater; out-of-sample: each fan run predicted from the others)", ""])
    text = compare.open_loop_table(r).splitlines()  # the fit, a blank line, the table, a blank line, a note
    end = 4 + len(r.rows)
    report.lines += textwrap.wrap(text[0], WIDTH) + [""]
    report.table("\n".join(text[2:4]), text[4:end], keys=1)
    report.lines += [wrapped for line in text[end:] for wrapped in textwrap.wrap(line, WIDTH) or [""]]
    report.traces = [Trace(f"{name}: " + ("the plant fitted to this run (in-sample)" if name == compare.ONION_NO_FAN
                                          else "the plant's prediction (out-of-sample)"), t, logged, twin)
                     for name, (t, logged, twin) in r.traces.items()]
    report.out_of_sample = [row["passed"] for row in r.rows]
    return report


# --- M303 ------------------------------------------------------------------------------------------


def _m303(args: argparse.Namespace, log: Log) -> Report:
    with progress_bar("fitting", MAX_EVALUATIONS * len(m303_compare.MODELS), "evaluations") as fits, \
            progress_bar("twin M303", m303_compare.MAX_RUN_S, "s") as run:
        try:
            r = m303_compare.m303_check(args.log, args.heater, args.ambient, args.fit_cycles, args.plant,
                                        on_evaluation=fits.update, on_progress=lambda s: run.update(s - run.n))
        except m303_compare.NoRelay as error:
            raise compare.Unusable(str(error)) from None
    report = Report(["M303: the twin's autotune against the capture's printed cycles", ""])
    report.lines += [wrapped for line in m303_compare.heading(r) for wrapped in textwrap.wrap(line, WIDTH,
                                                                                            subsequent_indent="  ")]
    report.lines.append("")
    report.lines += text_tables(m303_compare.CYCLE_COLUMNS, [m303_compare.cycle_cells(row) for row in r.rows])
    if r.trace_rows:
        report.lines += ["", "the plant replaying the logged relay levels over the status trace:", ""]
        report.lines += text_tables(m303_compare.TRACE_COLUMNS, [m303_compare.trace_cells(t) for t in r.trace_rows])
    report.out_of_sample = [row.passed for row in r.out_of_sample()]
    if r.trace is not None:
        t, logged, sim, duty = r.trace
        report.traces = [Trace(f"{r.heater}: the capture's temperatures against the plant ({r.plant}) fed the "
                               "capture's heater power", t, logged, sim, duty)]
    return report


# --- output --------------------------------------------------------------------------------------


EXAMPLES = """examples:
  twin-compare klippy_stats.csv                    closed-loop replay and PID_CALIBRATE cross-check
  twin-compare klippy_stats.csv --plot replay.png  the same, with logged vs twin plotted
  twin-compare heattest_200.csv                    the onionheater open-loop fan prediction
  twin-compare m303_capture.txt --ambient 24       an M303 capture: the twin's M303 at its target, Tu and swing
  twin-compare m303_capture.txt --fit-cycles 2     fitted on the first two printed cycles, the rest predicted
  twin-compare m303_capture.txt --plant hotend     against a preset (or --plant OTHER_LOG: a plant fitted to it)
  twin-compare m303_bed.txt --heater heater_bed    a capture that lacks its M303 E-1 line
"""


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="twin-compare", description=__doc__, epilog=EXAMPLES + "\n" + EXIT_STATUS_HELP)
    parser.add_argument("log", type=Path, metavar="LOG", help="the hardware log")
    parser.add_argument("--plot", metavar="FILE", type=plot_path,
                        help="write logged vs twin to FILE (png, pdf, svg, ...); its folder must exist")
    parser.add_argument("--heater", choices=("extruder", "heater_bed"),
                        help="an M303 capture: the heater it tuned (default: from its M303 line or status lines)")
    parser.add_argument("--ambient", type=ranged_float(*AMBIENT_RANGE_C, "C"),
                        help="an M303 capture: the room temperature in C (default: the idle heater's reading, else "
                             "25 C)")
    sample = parser.add_mutually_exclusive_group()
    sample.add_argument("--fit-cycles", type=int, metavar="K",
                        help="an M303 capture: fit the first K printed cycles (and the trace up to them), predict "
                             "the later ones (default: fit all of them, in-sample)")
    sample.add_argument("--plant", metavar="PRESET_OR_LOG",
                        help="an M303 capture: the twin's plant instead of a fit to it: a preset (twin/plants.py) or "
                             "a log that twin-fit fits; every cycle is then out-of-sample")
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.fit_cycles is not None and args.fit_cycles < 1:
        parser.error(f"argument --fit-cycles: {args.fit_cycles}: at least one cycle")
    return args


# The checks by log format (tools/logs/registry.py: a reader's name is its format).
CHECKS: dict[str, Callable[[argparse.Namespace, Log], Report]] = {
    klipper_stats.STATS_CSV_READER.name: _stats,
    klipper_stats.KLIPPY_LOG_READER.name: _stats,
    heattest.READER.name: _heattest,
    m303.READER.name: _m303,
}


def _report(args: argparse.Namespace) -> Report:
    log = load_with_progress(args.log)
    if (args.fit_cycles is not None or args.plant is not None) and log.format != m303.READER.name:
        raise compare.Unusable("--fit-cycles and --plant need an M303 capture")
    if log.format not in CHECKS:
        raise compare.Unusable(f"no check for its format ({log.format}): the checks take {', '.join(CHECKS)}")
    return CHECKS[log.format](args, log)


def run(args: argparse.Namespace) -> int:
    report = _report(args)
    print("\n".join(report.lines + ["", report.summary()]))
    if args.plot and not report.traces:  # an M303 capture without a status trace: its cycles are the table above
        print(f"no plot: {args.log.name} has no temperature trace to draw, only the table above")
    elif args.plot:
        compare_figure.write(args.plot, report.traces, f"{args.log.name}: the log against the twin")
        print(f"plot written to {args.plot}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)

    def describe(exc: BaseException) -> str:
        return f"{args.log}: not usable: {(exc.strerror or exc) if isinstance(exc, OSError) else exc}"

    return run_main("twin-compare", lambda: run(args),
                    errors=(LogError, compare.Unusable, NotFittable, OSError, UserError), describe=describe)


if __name__ == "__main__":
    sys.exit(main())
