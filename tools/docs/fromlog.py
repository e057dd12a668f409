"""Tune from every log that states the printer's gains: the plants it allows, the answer, and the proof of
the answer and of the printer's own gains on every plant, as ``twin-tune --from-log LOG --noise 1`` gives.

For each capture in hardware_logs that states gains (an M303 capture's printed Kp/Ki/Kd, a klippy.log's
config dump for each heater with a PID, each entry of the PID_CALIBRATE collection; tools/tuning/
reference.py), the log is read as a user would paste it, every plant it allows is found (tools/tuning/
allowed.py), the tune runs on its loop at its target against the printer's gains with 1 LSB of ADC noise
and the default budget, and the proof (10 seeds on every plant) decides: new gains or keep your gains
(tools/tuning/verdict.py; where no plant both fits the log and replays it, keep your gains: the twin cannot
model the heater well enough to beat them). Each capture's table gives, per plant, trips, worst hold error,
worst overshoot and mean duty chatter for the answer (or, where the answer is to keep your gains, the
closest candidate) and for the printer's own gains, and whether the candidate is within the verdict's bounds there. Every
row is in-sample: the plants were fitted to the capture they are scored on (docs/tuning.md's cross-
validation scores tunes out of sample). ``python -m tools.docs.fromlog --doc docs/tuning.md`` rewrites
the section; ``--only NAME`` runs the captures whose file names contain NAME.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.cli.args import doc_page
from tools.entry import OneLineParser, run_cli
from tools.ident.log_fit import LogFitOptions
from tools.ident.segments import NotFittable
from tools.logs import Log, LogError, M303Log, StatsLog, hardware_logs_dir, load_log
from tools.tuning.answer import no_model_lines
from tools.tuning.problems import NoModel, build_problem, source_of
from tools.tuning.proof import ProofRow
from tools.tuning.reference import from_log
from tools.tuning.tuner import DEFAULT_BUDGET, Proven, proven, tune
from tools.tuning.verdict import member_misses
from tools.validation.doc_compare import publish_section

BEGIN, END = "<!-- fromlog: begin", "<!-- fromlog: end -->"
COMMAND = "python -m tools.docs.fromlog --doc docs/tuning.md"
NOISE_LSB = 1.0
SEED = 0
HEATERS = ("extruder", "heater_bed")


@dataclass(frozen=True)
class Case:
    """One heater of one capture that states its gains: the file, the heater, a PID_CALIBRATE entry."""

    path: Path
    heater: str
    entry: int | None = None

    @property
    def label(self) -> str:
        entry = f" entry {self.entry}" if self.entry is not None else ""
        return f"`{self.path.name}`{entry}, {self.heater}"


def cases(folder: Path, only: str | None = None) -> list[Case]:
    """Every heater of every capture in the folder that states the printer's gains."""
    found = []
    for path in sorted(folder.iterdir()):
        if path.suffix not in (".txt", ".csv") or (only and only not in path.name):
            continue
        try:
            log = load_log(path)
        except LogError:
            continue
        found += _cases_of(path, log)
    return found


def _cases_of(path: Path, log: Log) -> list[Case]:
    if isinstance(log, list):
        return [Case(path, r.heater or "extruder", k) for k, r in enumerate(log) if r.kp > 0]
    heaters = HEATERS if isinstance(log, (StatsLog, M303Log)) else ()
    return [Case(path, h) for h in heaters if from_log(log, h) is not None]


@dataclass(frozen=True)
class Outcome:
    case: Case
    text: str  # the answer's line, or why the capture cannot be tuned
    proof: Proven | None = None
    kept: bool = False  # keep your gains without a proof: no plant the log allows (tools/tuning/answer.py)


def run_case(case: Case, budget: int = DEFAULT_BUDGET) -> Outcome:
    """The capture tuned as twin-tune --from-log tunes it, at 1 LSB of noise, proven."""
    log = load_log(case.path)
    options = LogFitOptions(heater=case.heater, segment=case.entry)
    try:
        source = source_of(log, case.path.name, options)
        problem = build_problem(source, noise_lsb=NOISE_LSB)
    except NoModel as exc:  # the log states the gains (every case does): keep them, and why
        _, lines = no_model_lines(exc, exc.printer)
        return Outcome(case, lines[0].replace("answer: keep your gains", "Answer: **keep your gains**", 1), kept=True)
    except (NotFittable, ValueError) as exc:
        return Outcome(case, f"not tuned: {exc}")
    printer = source.printer
    yours = None if printer is None else np.array([printer.gains.kp, printer.gains.ki, printer.gains.kd])
    proof = proven(tune(problem, budget=budget, seed=SEED, yours=yours))
    plants = [m.label for m in problem.ensemble.members] if problem.ensemble else ["the fit"]
    head = (f"{problem.loop} loop, {problem.scenario.target_c:g} C; yours: {proof.yours.gains} "
            f"({printer.source if printer else 'the firmware autotune'}); {len(plants)} plants: {', '.join(plants)}")
    verdict = proof.verdict
    option = f"; option: {verdict.shown}: {verdict.trade}" if verdict.trade else ""
    answer = f"**keep your gains**: {verdict.why}{option}" if verdict.keep else \
        f"**new gains** {proof.answer.gains if proof.answer else ''}: {verdict.why}"
    return Outcome(case, f"{head}. Answer: {answer}", proof)


def _pair(ours: float, yours: float, digits: int = 2) -> str:
    return f"{ours:.{digits}f} / {yours:.{digits}f}"


def table(proof: Proven) -> list[str]:
    """Per plant: the answer (or the closest candidate) against yours, and whether it is within bounds."""
    shown = proof.verdict.shown
    by = {(r.method, r.member): r for r in proof.rows}
    members = list(dict.fromkeys(r.member for r in proof.rows))
    lines = ["| plant | candidate | trips | hold C, worst | overshoot C, worst | chatter, mean | within bounds |",
             "|---|---|---|---|---|---|---|"]
    for member in members:
        yours: ProofRow = by[(proof.yours.method, member)]
        ours = by.get((shown, member)) if shown else None
        if ours is None:
            lines.append(f"| {member} | (none) | - / {yours.trips} | - / {yours.hold_error_c[1]:.2f} | "
                         f"- / {yours.overshoot_c[1]:.2f} | - / {yours.chatter[0]:.3f} | - |")
            continue
        misses = member_misses(ours, yours)
        lines.append(f"| {member} | {shown} | {ours.trips} / {yours.trips} | "
                     f"{_pair(ours.hold_error_c[1], yours.hold_error_c[1])} | "
                     f"{_pair(ours.overshoot_c[1], yours.overshoot_c[1])} | "
                     f"{_pair(ours.chatter[0], yours.chatter[0], 3)} | {'yes' if not misses else '; '.join(misses)} |")
    return lines


def markdown(outcomes: list[Outcome], budget: int) -> str:
    new = sum(1 for o in outcomes if o.proof is not None and not o.proof.verdict.keep)
    keep = sum(1 for o in outcomes if o.kept or (o.proof is not None and o.proof.verdict.keep))
    lines = [f"Written by `{COMMAND}`: every capture in hardware_logs that states the printer's gains, tuned as "
             f"`twin-tune --from-log LOG --noise {NOISE_LSB:g}` tunes it (DE {budget} evaluations, seed {SEED}; the "
             "proof: 10 noise seeds on every plant the log allows). Each table: the answer (new gains), or where the "
             "answer is to keep your gains the closest candidate, against your gains (candidate / yours), per plant; "
             "within bounds: no trip, hold at most yours x 1.1 + 0.02 C, overshoot at most yours + 0.5 C. Where no "
             "plant both fits a capture and replays it, the answer is keep your gains, with every structure tried "
             "and why, and no table. Every row is in-sample: the plants are fitted to the capture they are scored "
             "on.", "",
             f"{len(outcomes)} heaters: new gains on {new}, keep your gains on {keep}, not tuned on "
             f"{len(outcomes) - new - keep}.", ""]
    for o in outcomes:
        lines += [f"**{o.case.label}**: {o.text}", ""]
        if o.proof is not None:
            lines += table(o.proof) + [""]
    return "\n".join(lines)


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.fromlog", description=__doc__.splitlines()[0])
    parser.add_argument("--doc", type=doc_page(BEGIN, END), help="rewrite the section of this file (docs/tuning.md)")
    parser.add_argument("--budget", type=int, default=DEFAULT_BUDGET, help="DE evaluations per tune (default: "
                        "%(default)s)")
    parser.add_argument("--only", metavar="NAME", help="only the captures whose file names contain NAME")
    return parser


def run(args: argparse.Namespace) -> int:
    outcomes = []
    for case in cases(hardware_logs_dir(), args.only):
        outcome = run_case(case, args.budget)
        print(f"{case.label}: {outcome.text}", file=sys.stderr, flush=True)
        outcomes.append(outcome)
    body = markdown(outcomes, args.budget)
    return publish_section(body, args.doc, BEGIN, END)


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
