"""What twin-tune's and twin-fit's command lines show before any tuning: the defaults of their options and
their exit status. Light (no numba, no scipy), so that ``--help`` prints them at once; the modules that use
each value import it from here."""

from __future__ import annotations

from tools.entry import INTERNAL_STATUS_HELP
from tools.tuning.optim import METHODS
from tools.tuning.rules import RULES

LOOPS = ("marlin", "klipper", "kalico", "ideal")  # the loops a problem runs in (tools/tuning/evaluate.py)
LOOP_AUTO = "auto"  # twin-tune --loop auto: the loop the log's printer runs (Marlin for a preset)
LOOP_BOTH = "both"  # twin-tune --loop both: tune and prove on Marlin's loop, then on Klipper's
HOTEND_TARGET_C, BED_TARGET_C = 210.0, 60.0  # a tune's setpoint where none is given (tools/tuning/problems.py)
DEFAULT_BUDGET = 900  # optimiser evaluations: 20 generations of DE's default population of 45 (tools/tuning/tuner.py)
PROOF_SEEDS = 10  # noise seeds per plant in the proof (tools/tuning/proof.py)
CROSS_CHECK_S = 60.0  # the reference engine re-runs this much of one proof run
DEFAULT_OBJECTIVE = "heater"  # tools/tuning/objectives.py

EXIT_ANSWER = 0
EXIT_UNSAFE = 1
EXIT_NO_MODEL = 3
EXIT_CODES = """exit status:
  0  a verdict: new gains that beat yours on every plant the log allows, or keep your gains and why
     (also where the twin cannot model the heater well enough to beat them: no plant both fits the log
     and replays it, or your gains trip on one)
  1  no safe answer where your gains are not known: the firmware's autotune on the twin trips on some
     plant and nothing tried beats it (the report says where)
  2  bad input (an option, a log that cannot be read or fitted, a controller), said in one line
  3  neither a model nor a reference: no plant both fits the log and replays it, and it states no gains
     (--current-gains gives them)
""" + INTERNAL_STATUS_HELP + "\n"


def rule_names() -> list[str]:
    """The tuning rules (tools/tuning/rules.py), by name."""
    return list(RULES)


def optimiser_names() -> list[str]:
    """The optimisers (tools/tuning/optim), by name."""
    return list(METHODS)


def methods() -> list[str]:
    """Every value ``--method`` takes."""
    return rule_names() + optimiser_names() + ["all", "auto", "rules"]
