"""The answer a user reads, one per capture: twin-tune and twin-fit print these same lines and exit with the
same status.

- new gains: the verdict's line (tools/tuning/verdict.py), then the settings ready to paste;
- keep your gains: why, and the closest candidate that never trips as an option line with its trade and
  the command that takes it, for a user who values that trade more than the verdict's bounds do;
- keep your gains where the twin has no model of the heater (``NoModel``: no plant both fits the log and
  replays it) or where your gains trip on a plant the log allows: the twin cannot model this heater well
  enough to beat them, and why.

Exit status (EXIT_*): 0 a verdict; 1 no safe answer where the printer's gains are not known (the
reference, the firmware's autotune on the twin, trips on some plant and nothing beats it); 3 neither a
model nor a reference (no plant the log allows, and no gains stated); 2 (bad input) is the command's.
"""

from __future__ import annotations

import numpy as np

from firmware_port.kalico import mpc_options, pid_options, section
from tools.tuning.evaluate import Problem, kalico_mpc_config
from tools.tuning.defaults import DEFAULT_OBJECTIVE, EXIT_ANSWER, EXIT_NO_MODEL, EXIT_UNSAFE
from tools.tuning.gains import Gains
from tools.tuning.problems import NoModel
from tools.tuning.proof import CROSS_CHECK_S, PROOF_SEEDS
from tools.tuning.reference import PrinterGains
from tools.tuning.tuner import DEFAULT_BUDGET, YOURS, Proven, Step, TuneResult, proven, tune

CANNOT_MODEL = "the twin cannot model this heater well enough to beat them"


def default_tune(problem: Problem, printer: PrinterGains | None, budget: int = DEFAULT_BUDGET,
                 seeds: int = PROOF_SEEDS, on_step: Step | None = None) -> tuple[TuneResult, Proven]:
    """twin-tune's default tune of the problem against the printer's gains, and its proof: what twin-fit
    prints too."""
    result = tune(problem, DEFAULT_OBJECTIVE, "auto", budget, 0, yours=printer_params(problem, printer),
                  on_step=on_step)
    return result, proven(result, seeds, cross_check_s=CROSS_CHECK_S, on_step=on_step)


def printer_params(problem: Problem, printer: PrinterGains | None) -> np.ndarray | None:
    """The printer's gains as the problem's parameters (Kp, Ki, Kd), the set to beat; None where there are
    none or the controller is no PID."""
    if printer is None or not problem.controller.pid:
        return None
    return np.array([printer.gains.kp, printer.gains.ki, printer.gains.kd])


def settings_lines(problem: Problem, params: np.ndarray, is_bed: bool, proven_: bool = True) -> list[str]:
    """Ready to paste, for the loop that proved it (or marked unproven): Marlin's M301/M304 and
    Configuration.h, Klipper's section, or Kalico's (its PID or its MPC, as SAVE_CONFIG writes them); for
    other controllers their parameters."""
    heater = "heater_bed" if is_bed else "extruder"
    if problem.loop == "kalico":
        options = pid_options(*params) if problem.controller.pid else \
            mpc_options(kalico_mpc_config(problem, params))
        return [f"Kalico printer.cfg ({'proven on' if proven_ else 'UNPROVEN, from'} the Kalico loop):",
                *("  " + line for line in section(heater, options).splitlines())]
    if not problem.controller.pid:
        return [f"{problem.controller.name} parameters (the firmware's units), from the {problem.loop} loop"
                f"{'' if proven_ else ', UNPROVEN'}:",
                *(f"  {p.name} = {v:.6g} {p.unit}".rstrip() for p, v in zip(problem.controller.params, params))]
    gains = Gains(*(float(v) for v in params))
    if problem.loop == "klipper":
        return [f"Klipper printer.cfg ({'proven on' if proven_ else 'UNPROVEN, from'} the Klipper loop):",
                *("  " + line for line in gains.klipper_section(heater).splitlines())]
    where = "proven on the Marlin loop" if proven_ and problem.loop == "marlin" else \
        "UNPROVEN, from the Marlin loop" if problem.loop == "marlin" else "from the papers' idealised loop, unproven"
    return [f"Marlin ({where}; send, then M500 to keep it):", f"  {gains.marlin_command(bed=is_bed)}", "  M500",
            "Marlin Configuration.h:", *("  " + line for line in gains.marlin_defines(bed=is_bed).splitlines())]


def reference_name(problem: Problem, yours: str) -> str:
    """What the reference to beat is, for the verdict's line."""
    what = "gains" if problem.controller.pid else "parameters"
    return f"your {what}" if yours == YOURS else f"{yours}'s {what}"


def verdict_lines(problem: Problem, proof: Proven, is_bed: bool, printer: PrinterGains | None
                  ) -> tuple[int, list[str]]:
    """The exit status and the answer's lines (module docstring)."""
    verdict, name = proof.verdict, reference_name(problem, proof.yours.method)
    if not verdict.keep:
        assert proof.answer is not None
        return EXIT_ANSWER, [f"answer: new gains ({proof.answer.method}): {verdict.why}",
                             *settings_lines(problem, proof.answer.params, is_bed)]
    tripped = sorted({r.member for r in proof.rows if r.method == proof.yours.method and r.trips})
    if not tripped:
        return EXIT_ANSWER, [f"answer: keep {name}: {verdict.why}", *option_lines(problem, proof, is_bed)]
    where = f"they trip on {len(tripped)} of the plants the log allows ({'; '.join(tripped)})"
    if printer is not None:
        return EXIT_ANSWER, [f"answer: keep {name}: {CANNOT_MODEL}: on the twin {where}; {verdict.why}",
                             *option_lines(problem, proof, is_bed)]
    return EXIT_UNSAFE, [f"answer: keep {name}: {verdict.why}, and {where}: no safe answer was found"]


def option_lines(problem: Problem, proof: Proven, is_bed: bool) -> list[str]:
    """Under keep your gains, the closest candidate that never trips: its trade, what it misses, its command."""
    verdict = proof.verdict
    method = verdict.shown
    if not verdict.trade or method is None:
        return []
    row = next(r for r in proof.rows if r.method == method)
    missed = verdict.misses[method]
    member, why = next(iter(missed.items()))
    more = f" (and on {len(missed) - 1} more)" if len(missed) > 1 else ""
    described = str(Gains(*(float(v) for v in row.params))) if problem.controller.pid else \
        problem.controller.describe(row.params)
    head = (f"option: {method} {described}: {verdict.trade}; not the answer: it misses on {member}: "
            f"{'; '.join(why)}{more}. To take it anyway:")
    return [head, *("  " + line for line in settings_lines(problem, row.params, is_bed))]


def no_model_lines(error: NoModel, printer: PrinterGains | None) -> tuple[int, list[str]]:
    """The answer where no plant both fits the log and replays it: keep the printer's gains (they are
    what it runs), else nothing to answer."""
    if printer is None:
        return EXIT_NO_MODEL, [f"no answer: {error} (no gains to keep either: --current-gains gives yours)"]
    return EXIT_ANSWER, [f"answer: keep your gains ({printer.gains}: {printer.source}): {CANNOT_MODEL}: "
                         f"{error.allowed.why_none()}"]
