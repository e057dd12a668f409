"""Benchmarks (not tests): ``python -m tools.bench WHAT``; ratios measured in one run.

WHAT is twin, tune, twin-tune, protocol, scaling, startup or fallback. Each prints the command and the machine (CPUs, model,
load, date, commit) before its lines; ``--doc FILE`` also rewrites FILE's section between
``<!-- bench WHAT: begin`` and ``<!-- bench WHAT: end -->`` (docs/performance.md), checked before any work.

``twin``:
- single twin, hotend + bed, fixed-point PID, full ISR fidelity, 600 s heat-and-hold: real-time
  factor of the fast engine, of the tick-by-tick reference engine, and their ratio;
- a batch of 1000 hotend twins x 600 s with different gains: wall time and firmware control
  periods per second;
- the same linear plant open loop on a PWM input: the engine's exact tick maps vs
  scipy.signal.lsim on the same 1.024 ms grid, time ratio and largest difference.

``tune``: what a tuner pays for an evaluation, in one run:
- a batch of 1000 hotend twins (the tuning plant) x 600 s, full ISR fidelity, run as a tuner runs
  it (no trace kept: the heater objective's inputs streamed; lanes on every CPU): the cost of one
  600-s firmware-in-the-loop evaluation, against one evaluation of seed 000's idealised loop
  (its second-order plant closed with a PID by scipy.signal, step over 50 s, 1000 points), and
  their ratio; firmware control periods per second; the share of the lanes' periods run once for
  all (the heat-up before the PID band, ``BatchTwin``'s shared prefix); memory per lane; the same
  batch on the numpy lanes (which run every lane's every period) for comparison;
- a user's controller on the batch through its own lane law (tests/helpers/integer_pi.py: an integer
  PI with back-calculation anti-windup, defined outside the library) against the built-in PID: CPU
  per evaluation, same lanes, horizon and plant, as a tuner runs them (target: within 2x);
- the wall time of a differential-evolution tune of the three gains (population 45, 100
  generations, every population one batch) with twin-tune's heater objective on its default
  scenario;
- twin-tune's default tune (rules, references, DE) of the tuning plant on the Marlin loop and on the
  Klipper loop, and their ratio;
- the same DE tune on a dead-time plant (seed001_fopdt), on the radiating fit of hotend_cartridge
  and with 1 LSB of ADC noise: every one on the batch.

``twin-tune``: the command as a user runs it, in its own process (interpreter, imports, fit, tune and proof),
after one untimed warm-up run that leaves numba's compiled kernels in its cache:
- ``twin-tune --plant hotend_cartridge --target 210``, the default tune (target: 15 s wall), and the same
  with ``--controller mpc`` (target: at most 3 x the default tune's wall time);
- ``twin-tune --from-log`` on every M303 capture and every klippy.log (its Stats lines) in the hardware
  logs, on each heater a klippy.log reports (target: 30 s wall each);
each one's wall and CPU time (its process and the threads it starts), exit status and verdict.

``scaling``: cost per evaluation against lanes and horizon for each path of the batch (linear,
noisy, dead time, radiating, the fuzzy PI, the Klipper loop), and against dask workers
(docs/scaling.md).

``startup``: the CPU time (its process, resource.getrusage of children) of each command's ``--help``
(target: 0.5 s) and of twin-serial until it prints its link (target: 1 s), the median of ``--runs``.
``fallback``: the batch without numba (NUMBA_DISABLE_JIT=1, HEATER_TWIN_KERNEL=numpy, as a platform without
numba's wheels runs it) against the compiled loop, CPU ratios in one run: 1000 lanes x 600 s on the numpy
lanes (linear plant), 16 lanes of a dead-time plant on the loop as plain Python, and twin-tune's default
tune in its own process (and whether it prints the same report).

``protocol``: twin-serial ``--speed max`` in its own process, pyserial on its pty, as a host:
- M105 round trip, wall milliseconds, median and 99th percentile;
- numbered, checksummed G1 lines streamed with 1 and with BUFSIZE (4) lines awaiting their ok:
  lines per second, oks and resends (none expected: a clean wire loses nothing);
- the wall time of ``M303 E0 S210 C8`` on the default hotend.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import shlex
import subprocess
from datetime import UTC, datetime
from pathlib import Path

from firmware_port.marlin.constants import TICKS_PER_READING
from tools.cli.args import section_page
from tools.entry import EXIT_STATUS_HELP, OneLineParser, run_cli
from tools.logs.location import DEFAULT_LOGS, LOGS_ENV
from tools.validation.doc_compare import write_section
from twin.clock import TICK_S
from twin.limits import DURATION_MAX_S, THREADS_ENV, TRACE_MAX_BYTES, UserError, checked

# -- the report: the command, the machine, the lines; --doc --------------------------------------------
ROOT = Path(__file__).resolve().parents[1]
CAPTURES = ("m303_*.txt", "klippy_stats_*.csv")  # every M303 capture, every klippy.log's Stats lines
STARTUP_RUNS = 5  # the median of these, per command
BENCHES = ("twin", "tune", "twin-tune", "protocol", "scaling", "startup", "fallback")
# the options each benchmark reads; all but --seed set its size
OPTIONS = {"twin": ("duration", "lanes", "seed"), "tune": ("duration", "lanes", "seed"),
           "twin-tune": ("budget", "proof", "captures"), "protocol": ("requests", "lines"), "scaling": ("seed",),
           "startup": ("runs",), "fallback": ("duration", "lanes", "seed", "budget", "proof")}
SETTINGS_ENV = ("OPENBLAS_NUM_THREADS", THREADS_ENV)  # environment that changes what a run measures
NOT_MEASURED = ("NOT A MEASUREMENT: smaller than the defaults, a check that the benchmark runs; "
                "re-run without the size options on a quiet machine")


def markers(what: str) -> tuple[str, str]:
    """The markers of a benchmark's section in a page (--doc)."""
    return f"<!-- bench {what}: begin", f"<!-- bench {what}: end -->"


def _non_default(args: argparse.Namespace, parser: argparse.ArgumentParser) -> dict[str, object]:
    return {name: getattr(args, name) for name in OPTIONS[args.what]
            if getattr(args, name) != parser.get_default(name)}


def command_line(args: argparse.Namespace, parser: argparse.ArgumentParser) -> str:
    """The command that gives this run, its environment settings included."""
    env = [f"{name}={os.environ[name]}" for name in SETTINGS_ENV if name in os.environ]
    flags = [f"--{name} {value:g}" if isinstance(value, float) else f"--{name} {shlex.quote(str(value))}"
             for name, value in _non_default(args, parser).items()]
    doc = ["--doc", shlex.quote(str(args.doc))] if args.doc else []
    return " ".join([*env, "python -m tools.bench", args.what, *flags, *doc])


def _cpu_model() -> str:
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or "model unknown"


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def _commit(doc: Path | None) -> str:
    """The commit this run's code is at, and whether tracked files differ from it; the page being written
    does not count (an earlier benchmark's --doc changed it, not the code)."""
    head = _git("rev-parse", "--short", "HEAD")
    if head is None:
        return "unknown (no git checkout)"
    exclude = [f":(exclude){doc.resolve()}"] if doc is not None else []
    changed = _git("status", "--porcelain", "--untracked-files=no", "--", str(ROOT), *exclude)
    return head if changed == "" else f"{head} with uncommitted changes" if changed else f"{head} (changes unknown)"


def machine(doc: Path | None = None) -> str:
    """Where and when this run happens: what its wall times hold for."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (f"machine: {cpus} CPUs ({_cpu_model()}), load average {os.getloadavg()[0]:.2f} over the minute before; "
            f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC, commit {_commit(doc)}; the numbers below come from this "
            "one run")


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.bench", description=__doc__.splitlines()[0], epilog=EXIT_STATUS_HELP)
    parser.add_argument("what", choices=BENCHES, help="what to benchmark")
    parser.add_argument("--duration", type=float, default=600.0,
                        help="twin, tune: virtual seconds (default: %(default)s)")
    parser.add_argument("--lanes", type=int, default=1000, help="twin, tune: batch lanes (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1,
                        help="twin, tune, scaling: seed of the random gains and of DE (default: %(default)s)")
    parser.add_argument("--budget", type=int, help="twin-tune: its --budget (default: its own)")
    parser.add_argument("--proof", type=int, help="twin-tune: its --proof (default: its own)")
    parser.add_argument("--captures", metavar="GLOB",
                        help=f"twin-tune: the captures in the hardware logs to tune (default: {' and '.join(CAPTURES)})")
    parser.add_argument("--requests", type=int, default=500, help="protocol: M105 round trips (default: %(default)s)")
    parser.add_argument("--lines", type=int, default=5000, help="protocol: G1 lines per stream (default: %(default)s)")
    parser.add_argument("--runs", type=int, default=STARTUP_RUNS,
                        help="startup: runs of each command, the median reported (default: %(default)s)")
    parser.add_argument("--doc", type=Path, metavar="FILE",
                        help="also rewrite FILE's section between '<!-- bench WHAT: begin' and "
                             "'<!-- bench WHAT: end -->' (docs/performance.md)")
    return parser


def measure(args: argparse.Namespace) -> list[str]:
    """The benchmark's lines (the cases and their libraries imported here, not at --help)."""
    from tools import benchmarks as b

    if args.what == "twin":
        return b.bench_single(args.duration) + b.bench_batch(args.lanes, args.duration, args.seed) + \
            b.bench_open_loop(args.duration)
    if args.what == "tune":
        plant = b.tune_plant()
        return (b.bench_evaluation_cost(plant, args.lanes, args.duration, args.seed, n_seed000=200)
                + b.bench_user_law_cost(plant, args.lanes, args.duration, args.seed)
                + b.bench_de_tune(plant.preset, args.seed) + b.bench_loop_tunes(plant.preset, args.seed)
                + b.bench_batch_tunes(args.seed))
    if args.what == "twin-tune":
        sizes = [word for name in ("budget", "proof") if getattr(args, name) is not None
                 for word in (f"--{name}", str(getattr(args, name)))]
        return b.bench_twin_tune((args.captures,) if args.captures else CAPTURES, sizes)
    if args.what == "scaling":
        return b.bench_scaling(args.seed)
    if args.what == "startup":
        return b.bench_startup(args.runs)
    if args.what == "fallback":
        sizes = [word for name in ("budget", "proof") if getattr(args, name) is not None
                 for word in (f"--{name}", str(getattr(args, name)))]
        return b.bench_fallback(args.lanes, args.duration, args.seed, sizes)
    return b.bench_protocol(args.requests, args.lines)


def _memory_bytes() -> int:
    """This machine's physical memory."""
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_sizes(args: argparse.Namespace) -> None:
    """The size options, before any work: counts of at least 1, a batch whose records fit this machine's
    memory (and TRACE_MAX_BYTES), captures named by a pattern inside the hardware logs."""
    for name in ("lanes", "requests", "lines", "runs"):
        if getattr(args, name) < 1:
            raise UserError(f"--{name} {getattr(args, name)}: must be at least 1")
    checked("--duration", args.duration, 0.0, DURATION_MAX_S, "s", above=True)
    from twin.batch import RECORD_LANE_BYTES, RECORD_ROW_BYTES  # numba: not at --help

    rows = args.duration / (TICKS_PER_READING * TICK_S)
    need = rows * (RECORD_LANE_BYTES * args.lanes + RECORD_ROW_BYTES)
    have = min(TRACE_MAX_BYTES, _memory_bytes())
    if need > have:
        raise UserError(f"--lanes {args.lanes}: {args.duration:g} s of their records would take "
                        f"{need / 2**30:.3g} GiB, more than the {have / 2**30:.3g} GiB allowed here; give fewer "
                        "--lanes or a shorter --duration")
    if args.captures is not None and Path(args.captures).is_absolute():
        raise UserError(f"--captures {args.captures}: a pattern inside the hardware logs folder "
                        f"(${LOGS_ENV}, else {DEFAULT_LOGS}), not an absolute path")


def run(args: argparse.Namespace) -> int:
    check_sizes(args)
    parser = build_parser()
    if args.doc is not None:
        try:
            section_page(args.doc, *markers(args.what))
        except ValueError as exc:
            raise UserError(f"--doc {args.doc}: {exc}") from None
    sized = any(name != "seed" for name in _non_default(args, parser))
    report = [command_line(args, parser), machine(args.doc), *([NOT_MEASURED] if sized else []), *measure(args)]
    print("\n".join(report))
    if args.doc is not None:
        write_section(args.doc, "```\n" + "\n".join(report) + "\n```\n", *markers(args.what))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
