"""Section 4 of docs/validation.md: the M303 captures, in sample and out of sample, under a protocol
written down (PROTOCOL) before its out-of-sample scores were generated.

``m303_section(logs_dir)`` runs the checks of tools/validation/m303_compare.py on every capture in
M303_RUNS and returns the section's lines and its out-of-sample tally.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tools.ident.relay_loop import NoOscillation, relay_cycle
from tools.ident.relay_points import marlin_points
from tools.logs import results_only
from tools.validation import m303_compare
from tools.validation.m303_compare import IN, OUT, M303Comparison, NoRelay, verdict
from tools.validation.tables import markdown_table

# The captures that hold one M303 run with printed cycles (hardware_logs README D), with the heater
# where the capture does not say it (the Prusa bed run's M303 E-1 line is not in the excerpt).
M303_RUNS = {
    "m303_bed_artillery_genius_pro_S60_configs641.txt": None,
    "m303_hotend_artillery_genius_pro_S210_configs641_partial.txt": None,
    "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt": None,
    "m303_bed_and_hotend_octoprint_calibrationcompanion26_partial.txt": "heater_bed",
    "m303_hotend_S250_trace_marlin8081_partial.txt": None,
}
NOT_RUNS = {
    "m303_hotend_single_cycle_lines_skr_marlin14486.txt": "three result lines of three separate runs, not one run",
    "m303_hotend_C1_degenerate_marlin6316.txt": "C1: one half-cycle, no printed Tu",
    "m303_hotend_C2_degenerate_prusa_buddy5306.txt": "C2: no printed Tu (and elided by its author)",
    "m303_hotend_repetier_davinci356.txt": "Repetier's relay: its own levels and rules",
}
MIN_PRINTED = 2  # cycles: one to fit, one to predict

PROTOCOL = (
    "Protocol, fixed before the out-of-sample scores below were generated: this text and the generator "
    "(tools/docs/validation_m303.py, tools/validation/m303_compare.py) were committed first, the scores "
    "in a later commit, and nothing here was changed after they were seen (`git log -- docs/validation.md "
    "tools/validation/` shows the order). While the method was built, trial fits of the first cycles of the "
    "Ender 3 V3 SE and Prusa bed captures were run (to choose how the twin's ADC noise is set for a plant "
    "fitted to relay results; the rule in step 5 comes from Widrow's quantisation theorem, not from those "
    "numbers).",
    "1. Captures: those holding one M303 run with printed cycles (README D), listed below; the tuned heater's "
    "printed cycles are the ones that print Tu, min and max (Marlin prints Tu from the third switch-on on).",
    "2. Split: of N printed cycles, the first K = N // 2 are fitted and the other N - K predicted. A capture "
    f"with fewer than {MIN_PRINTED} printed cycles has too few: listed in-sample only.",
    "3. Fit (tools/ident/log_fit.py): each fitted cycle's printed results are a point of the loop (its relay "
    "levels from the bias line before it, or its own where the capture starts with it; t_high - t_low "
    "bracketed by Marlin's next bias update), compared with the model's own relay cycle at those levels "
    "(tools/ident/relay_loop.py, 5 s minimum half-cycle included), within the cycles' scatter (Tu 4 %, "
    "swing 13 %); where the capture has a 2 s status trace, its lines up to the K-th cycle's are fitted "
    "with them. three_node, sopdt and fopdt are fitted and the lowest AIC kept. Ambient: the idle heater's "
    "reading, else 25 C; power 40 W (hotend) or 220 W (bed), assumed; target: the M303 command's S, else "
    "the whole degree within every printed cycle's min..max nearest the trace's switches, else nearest that "
    "range's middle.",
    "4. Prediction: the twin's own M303 (firmware_port/marlin/autotune.py; Marlin 1.1 for a bed tuned by the "
    "Classic PID rule, else 2.1) on the fitted plant at the target, from ambient, for max(C of the command, "
    "N + 2, 8) cycles.",
    "5. The twin's ADC: a plant fitted to relay results already holds their reading noise (it reproduces "
    "them with a noiseless relay), so its conversions get only 0.5 LSB of Gaussian dither, the least that "
    "lets Marlin's sum of 16 conversions resolve a crossing finer than one step (a mean-reading bias under "
    "1 % of a step); seeded (seed 0).",
    "6. Scored: the mean Tu and the mean swing (max - min) of the N - K later cycles against the means over "
    "the twin's cycles that print Tu. Goals: Tu within 10 % and swing within 25 % for a capture with its "
    "status trace; Tu within 15 % and swing within 30 % from the result lines alone. The relay floor: "
    "Marlin's half-cycles last at least 5 s, so Tu cannot fall below 10 s; a Tu of the log or of the twin "
    "within 10 % of that floor (11 s or less) is set by that rule more than by the plant: it is flagged, "
    "not judged, and the swing alone decides.",
    "7. The result lines alone: each capture with status lines is copied with them deleted "
    "(tools/logs/m303.py results_only, in a temporary folder) and goes through steps 2-6 again.",
    "8. Also reported, not scored: the status trace replayed by the fitted plant under the logged relay "
    "levels, from the fit's start (RMSE over the fitted lines and over the later ones); and each capture "
    "fitted on all its printed cycles and its whole trace, the twin against all of them (in-sample).",
)
TABLE_COLUMNS = ("log", "heater", "data", "cycles fitted / predicted", "model", "Tu log / twin (s)", "Tu error",
                 "swing log / twin (C)", "swing error", "goal Tu / swing", "verdict")
TRACE_COLUMNS = ("log", "trace lines fitted (in-sample) / later (out-of-sample)", "readings",
                 "replay RMSE (C) in / out")


@dataclass
class M303Section:
    """The section's rows, the captures without enough cycles, the out-of-sample tallies and the evidence."""

    out_rows: list[list[str]] = field(default_factory=list)
    results_rows: list[list[str]] = field(default_factory=list)
    in_rows: list[list[str]] = field(default_factory=list)
    trace_rows: list[list[str]] = field(default_factory=list)
    too_few: list[str] = field(default_factory=list)
    tally: dict[str, list[int]] = field(default_factory=lambda: {"posted": [0, 0], "results_only": [0, 0]})
    evidence: list[str] = field(default_factory=list)


def _data(r: M303Comparison) -> str:
    assert r.fitted is not None
    return "printed cycles and status trace" if "trace" in r.fitted.result.evidence else "printed cycles"


def _cells(r: M303Comparison, row: m303_compare.CycleRow, fitted_cycles: str) -> list[str]:
    flag = " (floor)" if row.floor else ""
    assert r.fitted is not None
    return [f"`{r.file}`", r.heater, _data(r), fitted_cycles, r.fitted.result.model,
            f"{row.log.tu_s:.2f} / {row.twin.tu_s:.2f}", f"{100 * row.tu_rel:+.1f} %{flag}",
            f"{row.log.swing_c:.2f} / {row.twin.swing_c:.2f}", f"{100 * row.swing_rel:+.1f} %",
            f"{100 * row.goals[0]:g} % / {100 * row.goals[1]:g} %", verdict(row)]


def _trace_cells(r: M303Comparison) -> list[str] | None:
    rows = {t.sample: t for t in r.trace_rows}
    if OUT not in rows:
        return None
    inn, out = rows.get(IN), rows[OUT]
    fitted = f"{inn.first_line}..{inn.last_line}" if inn else "none"
    return [f"`{r.file}`", f"{fitted} / {out.first_line}..{out.last_line}",
            f"{inn.readings if inn else 0} / {out.readings}",
            f"{inn.rmse_c:.2f} / {out.rmse_c:.2f}" if inn else f"n/a / {out.rmse_c:.2f}"]


def miss_note(out: M303Comparison, inn: M303Comparison | None) -> str:
    """Computed evidence for an out-of-sample miss: the plant's own relay cycle at the later cycles'
    logged levels (is it the plant, or the twin's run?), the in-sample fit of the whole capture, and
    what the fitted cycles leave unidentified."""
    assert out.fitted is not None and out.capture is not None
    row = out.out_of_sample()[0]
    points = marlin_points(out.capture, out.heater, out.target_c)[row.first - 1:]
    try:
        cycles = [relay_cycle(out.spec, out.ambient_c, p.relay) for p in points]
        own = (f"the fitted plant's own relay cycle at the later cycles' logged levels gives Tu "
               f"{np.mean([c.tu_s for c in cycles]):.2f} s and swing {np.mean([c.swing_c for c in cycles]):.2f} C "
               f"against the log's {row.log.tu_s:.2f} s and {row.log.swing_c:.2f} C")
    except NoOscillation as error:
        own = f"the fitted plant does not oscillate at the later cycles' levels ({error})"
    open_ = [name for name, s in out.fitted.result.identification().items() if s != "identified"]
    whole = ""
    if inn is not None:
        (all_row,) = inn.rows
        whole = (f"; fitted on all {all_row.last} printed cycles the twin's Tu errs {100 * all_row.tu_rel:+.1f} % and "
                 f"its swing {100 * all_row.swing_rel:+.1f} % in-sample")
    return (f"`{out.file}` ({_data(out)}, {out.fitted.result.model}): {own}{whole}; not identified by the fitted "
            f"cycles: {', '.join(open_) or 'none'}.")


def _check(path: Path, heater: str | None, fit_cycles: int | None, section: M303Section,
           kind: str) -> M303Comparison | None:
    """One m303_check; a capture it cannot use is noted as too few and None returned."""
    try:
        r = m303_compare.m303_check(path, heater, fit_cycles=fit_cycles)
    except NoRelay as error:
        section.too_few.append(f"`{path.name}` ({kind}): {error}")
        return None
    return r


def _capture(path: Path, heater: str | None, section: M303Section) -> None:
    """In-sample, out-of-sample as posted, and out-of-sample from the result lines alone."""
    inn = _check(path, heater, None, section, "in-sample")
    if inn is None:
        return
    (row,) = inn.rows
    section.in_rows.append(_cells(inn, row, f"{_span(row.first, row.last)} / none"))
    n = row.last
    if n < MIN_PRINTED:
        section.too_few.append(f"`{path.name}`: {n} printed cycle: too few to fit one and predict another")
        return
    k = n // 2
    out = _check(path, heater, k, section, "out-of-sample")
    if out is not None:
        _score(out, inn, k, n, section, "posted")
        if (cells := _trace_cells(out)) is not None:
            section.trace_rows.append(cells)
    text = path.read_text()
    if (alone_text := results_only(text)) != text:  # the capture has status lines of its own
        with tempfile.TemporaryDirectory() as folder:
            copy = Path(folder) / path.name
            copy.write_text(alone_text)
            alone = _check(copy, heater, k, section, "result lines alone")
        if alone is not None:
            _score(alone, None, k, n, section, "results_only")


def _span(first: int, last: int) -> str:
    return f"{first}..{last}" if last > first else str(first)


def _score(r: M303Comparison, inn: M303Comparison | None, k: int, n: int, section: M303Section, kind: str) -> None:
    row = r.out_of_sample()[0]
    rows = section.out_rows if kind == "posted" else section.results_rows
    rows.append(_cells(r, row, f"{_span(1, k)} / {_span(k + 1, n)}"))
    section.tally[kind][0] += row.passed
    section.tally[kind][1] += 1
    if not row.passed:
        section.evidence.append("  - " + miss_note(r, inn))


def m303_section(logs_dir: Path) -> tuple[list[str], M303Section]:
    """Section 4's lines and its rows and tallies."""
    section = M303Section()
    for name, heater in M303_RUNS.items():
        _capture(logs_dir / name, heater, section)
    lines = ["## 4. M303 captures (Marlin relay autotune)", "", *PROTOCOL, "",
             "Captures that are not one run: " + "; ".join(f"`{n}` ({why})" for n, why in NOT_RUNS.items()) + ".",
             "", "### 4a. Out-of-sample: the later printed cycles predicted from the first half, as posted", "",
             *markdown_table(TABLE_COLUMNS, section.out_rows), "",
             "### 4b. Out-of-sample from the result lines alone (status lines deleted)", "",
             *markdown_table(TABLE_COLUMNS, section.results_rows), "",
             "The status trace replayed by the plant fitted on the first half (not scored):", "",
             *markdown_table(TRACE_COLUMNS, section.trace_rows), "",
             "### 4c. In-sample: fitted on all printed cycles (listed, not scored)", "",
             *markdown_table(TABLE_COLUMNS, section.in_rows), ""]
    if section.too_few:
        lines += ["Too few cycles to predict any: " + "; ".join(section.too_few) + ".", ""]
    return lines, section
