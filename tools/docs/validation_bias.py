"""Section 4d of docs/validation.md: the M303 captures' later cycles predicted with the relay's bias moving
as Marlin moves it (tools/validation/m303_bias.py), out of sample, and in sample in a table of its own.

``bias_section(logs_dir)`` returns the section's lines and its out-of-sample tally (rows within goal, rows).
"""

from __future__ import annotations

from pathlib import Path

from tools.docs.validation_m303 import M303_RUNS
from tools.validation.m303_bias import BiasCheck, Predicted, bias_check
from tools.validation.m303_compare import GOALS
from tools.validation.tables import markdown_table

GOAL_TU, GOAL_SWING = GOALS["results"]  # the result lines' goals: the fit here reads the printed cycles
COLUMNS = ("log", "heater", "cycles fitted / predicted", "sample", "prediction", "model", "Tu log / twin (s)",
           "Tu error", "swing log / twin (C)", "swing error", "bias printed after each, log / twin", "verdict")
PROTOCOL = (
    "Marlin moves the relay's bias and d at every switch-on (bias += d (t_high - t_low) / (t_high + t_low), "
    "clamped to 20..max_pow - 20; d = bias, or max_pow - 1 - bias above the middle) and prints them with the "
    "cycle's min and max: each printed cycle ran at the levels of the bias line before it. The plant is fitted "
    "as in step 3 on the first K = N // 2 printed cycles (and the status trace up to them); each later cycle is "
    "predicted by the model's own relay (tools/ident/relay_loop.py moving_bias_run: settled at the levels the "
    "cycle before ran at, then Marlin's relay with its bias moving by Marlin's rule on the model's whole-ms "
    "t_high and t_low). One step: cycle j at the bias and d Marlin printed after cycle j-1. Free run: from the "
    "bias and d printed after the K-th cycle, the model's relay runs on alone, its own bias moving (the logged "
    "bias lines after cycle K are predicted too). Scored: the mean Tu and swing of the predicted cycles; goals "
    f"as for the result lines (Tu {100 * GOAL_TU:g} %, swing {100 * GOAL_SWING:g} %). In-sample rows (fitted on every "
    "printed cycle, each predicted one step from the bias line before it) are listed apart and not scored."
)


def _cells(check: BiasCheck, how: str, p: Predicted, sample: str) -> list[str]:
    k = check.fit_cycles
    fitted = f"1..{k}" if k > 1 else "1"
    predicted = ", ".join(str(c) for c in p.cycles)
    passed = abs(p.tu_error) <= GOAL_TU and abs(p.swing_error) <= GOAL_SWING
    verdict = ("pass" if passed else "**miss**") if sample == "out-of-sample" else "listed, not scored"
    return [f"`{check.name}`", check.heater, f"{fitted} / {predicted}", sample, how, check.fitted.result.model,
            f"{p.tu_log_s:.2f} / {p.tu_twin_s:.2f}", f"{100 * p.tu_error:+.1f} %", f"{p.swing_log_c:.2f} / {p.swing_twin_c:.2f}",
            f"{100 * p.swing_error:+.1f} %", f"{', '.join(map(str, p.bias_log))} / {', '.join(map(str, p.bias_twin))}", verdict]


def bias_section(logs_dir: Path) -> tuple[list[str], tuple[int, int]]:
    """Section 4d's lines and its tally: every capture of M303_RUNS, out of sample where it prints two
    cycles or more."""
    out_rows, in_rows = [], []
    for name, heater in M303_RUNS.items():
        inn = bias_check(logs_dir / name, heater, fit_cycles=None)
        if inn.free_run is not None:
            out_rows += [_cells(inn, "one step", inn.one_step, "out-of-sample"),
                         _cells(inn, "free run", inn.free_run, "out-of-sample")]
            inn = bias_check(logs_dir / name, heater, fit_cycles=inn.printed)
        in_rows.append(_cells(inn, "one step", inn.one_step, "in-sample"))
    passed = sum(row[-1] == "pass" for row in out_rows)
    return ["### 4d. The relay with its bias moving (Marlin's rule), later cycles predicted", "", PROTOCOL, "",
            "Out-of-sample:", "", *markdown_table(COLUMNS, out_rows), "",
            "In-sample (fitted on every printed cycle; listed, not scored):", "", *markdown_table(COLUMNS, in_rows), ""], \
        (passed, len(out_rows))
