"""twin-compare LOG [--plot FILE]: the twin against one hardware log (tools/validation/compare.py).

A Klipper Stats log: the closed-loop replay and the PID_CALIBRATE cross-check for each heater
with a heat-up. A Marlin M303 capture with a status trace: a plant fitted to it runs the twin's
M303 at the same target and cycles; Tu, swing and gains, twin against log (tools/validation/m303_compare.py). An onionheater heattest (with its sibling runs in the same folder): the open-loop
fan prediction. Prints the error table(s); --plot writes logged vs twin with matplotlib.
A log that no check can use: one message on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tools.validation import compare, m303_compare
from tools.cli.args import OneLineParser, plot_path, ranged_float
from tools.ident.segments import NotFittable
from tools.logs import HeattestLog, LogError, M303Log, StatsLog, load_log

EXIT_UNUSABLE = 2


def _stats(path: Path, log: StatsLog):
    closed, tunes, lines = [], [], [compare.CLOSED_HEADER]
    tune_lines = [compare.AUTOTUNE_HEADER]
    for heater in compare.HEATERS:
        if not any(heater in s for s in log.sessions):
            continue
        try:
            r = compare.closed_loop_check(path, heater)
        except (compare.Unusable, NotFittable) as error:
            lines.append(compare.unusable_row(path.name, heater, str(error), compare.CLOSED_COLUMNS))
            continue
        closed.append(r)
        lines.append(compare.closed_loop_row(r))
        try:
            t = compare.autotune_check(path, heater, fit=r.fit)
        except (compare.Unusable, ValueError) as error:
            tune_lines.append(compare.unusable_row(path.name, heater, str(error), compare.AUTOTUNE_COLUMNS))
            continue
        tunes.append(t)
        tune_lines.append(compare.autotune_row(t))
    if not closed:
        raise compare.Unusable("no heater of this Klipper log has a heat-up to replay")
    text = "Closed-loop replay\n\n" + "\n".join(lines) + "\n\nPID_CALIBRATE cross-check\n\n" + "\n".join(tune_lines)
    return text, [(f"{r.heater}: {r.replay_label}", r.trace) for r in closed]


def _heattest(path: Path):
    if path.name not in compare.ONION_FILES or not all((path.parent / f).is_file() for f in compare.ONION_FILES[:3]):
        raise compare.Unusable("the open-loop check needs the onionheater no-fan and fan heattests side by side "
                               f"({', '.join(compare.ONION_FILES[:3])}); this heattest is not one of them")
    r = compare.open_loop_check(path.parent)
    traces = [(name, (t, logged, twin, None, None)) for name, (t, logged, twin) in r.traces.items()]
    return "Open-loop prediction (onionheater)\n\n" + compare.open_loop_table(r), traces


def _m303(path: Path, heater: str | None, ambient_c: float | None):
    try:
        r = m303_compare.m303_check(path, heater, ambient_c)
    except m303_compare.NoRelay as error:
        raise compare.Unusable(str(error)) from None
    seg = r.segment
    sim = r.fit.simulate(seg.t_s, seg.duty)
    traces = [(f"{r.heater}: relay trace and the fitted {r.fit.model}", (seg.t_s, seg.temp_c, sim, seg.duty, seg.duty))]
    return "M303: the twin's autotune on the plant fitted to the capture\n\n" + m303_compare.M303_HEADER + "\n" \
        + m303_compare.m303_row(r), traces


def _plot(file: str, traces) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(traces), 1, figsize=(10, 3.2 * len(traces)), squeeze=False)
    for ax, (title, (t, logged, twin, log_pwm, twin_pwm)) in zip(axes[:, 0], traces):
        ax.plot(t, logged, label="log", lw=1.2)
        ax.plot(t, twin, label="twin", lw=1.0)
        ax.set_title(title, fontsize=9)
        ax.set_ylabel("temp (C)")
        if log_pwm is not None:
            ax2 = ax.twinx()
            ax2.step(t, log_pwm, where="post", color="C2", lw=0.6, label="pwm log")
            ax2.step(t, twin_pwm, where="post", color="C3", lw=0.6, label="pwm twin")
            ax2.set_ylim(0, 1.05)
            ax2.set_ylabel("pwm")
        ax.legend(loc="lower right", fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(file)
    plt.close(fig)


EXAMPLES = """examples:
  twin-compare klippy_stats.csv                    closed-loop replay and PID_CALIBRATE cross-check
  twin-compare klippy_stats.csv --plot replay.png  the same, with logged vs twin plotted
  twin-compare heattest_200.csv                    the onionheater open-loop fan prediction
  twin-compare m303_capture.txt --ambient 24       an M303 capture: the twin's M303 at its target, Tu and swing
  twin-compare m303_bed.txt --heater heater_bed    a capture that lacks its M303 E-1 line
"""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = OneLineParser(prog="twin-compare", description=__doc__, epilog=EXAMPLES)
    parser.add_argument("log", type=Path, metavar="LOG", help="the hardware log")
    parser.add_argument("--plot", metavar="FILE", type=plot_path,
                        help="write logged vs twin to FILE (png, pdf, svg, ...); its folder must exist")
    parser.add_argument("--heater", choices=("extruder", "heater_bed"),
                        help="an M303 capture: the heater it tuned (default: from its M303 line or status lines)")
    parser.add_argument("--ambient", type=ranged_float(-40.0, 100.0, "C"),
                        help="an M303 capture: the room temperature in C (default: the idle heater's reading, else "
                             "25 C)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        log = load_log(args.log)
        if isinstance(log, StatsLog):
            text, traces = _stats(args.log, log)
        elif isinstance(log, HeattestLog):
            text, traces = _heattest(args.log)
        elif isinstance(log, M303Log):
            text, traces = _m303(args.log, args.heater, args.ambient)
        else:
            raise compare.Unusable(f"a {type(log).__name__ if not isinstance(log, list) else 'PID results list'}: "
                                   "the checks need a Klipper Stats log, an M303 capture with a trace or the "
                                   "onionheater heattests")
    except (LogError, compare.Unusable, NotFittable, OSError, ValueError) as error:
        print(f"twin-compare: {args.log}: not usable: {error}", file=sys.stderr)
        return EXIT_UNUSABLE
    print(text)
    if args.plot:
        _plot(str(args.plot), traces)
        print(f"plot written to {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
