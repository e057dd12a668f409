"""Seed 002's benchmark (section 3, tables 2-4): its printed F1-F23 results, the printed values no
algorithm can reach, and ours beside them.

Our rerun is ``tools.tuning.optim.benchmark`` on ``tools.tuning.benchfuncs``; ``python -m
tools.cli.benchfuncs`` prints ``benchmark_report`` after its own tables, and ``python -m tools.seeds
002`` judges every printed claim (``benchmark_verdicts``).
"""

from __future__ import annotations

from tools.seeds.report import (
    DIFFERS,
    IMPOSSIBLE,
    PAPER as PAPER_NAME,
    REPRODUCED,
    Budget,
    Progress,
    Verdict,
    no_progress,
)
from tools.tuning.benchfuncs import BENCHMARKS, PLAIN, SHIFTED
from tools.tuning.optim.benchmark import Results, fmt_g, forms_of, run_all, tasks_for, wins

ALGORITHMS = ("OCALO", "PSO", "ALO", "GALO", "IALO", "WALO")  # column order of tables 2-4

# Seed 002 tables 2 (mean), 3 (best, "optimal value") and 4 (worst) of F1-F23 over its runs, as
# printed (strings keep the printed precision). Table 2's ALO F4 reads "9.67E-05a": the stray "a"
# is dropped.
PRINTED_MEAN_TSV = """
F1  2.61E-12  1.18E-04  2.22E-09  1.04E-09  3.49E-10  3.92E-10
F2  2.12E-07  1.07E-02  3.12E-04  5.46E-06  1.12E-05  1.22E-05
F3  1.94E-11  3.17E-02  2.89E-06  8.29E-09  1.31E-09  2.51E-09
F4  3.27E-07  2.25E-02  9.67E-05  3.21E-05  8.78E-06  3.83E-06
F5  1.07E-03  9.17  6.08  3.46E-03  8.42E-03  1.25E-03
F6  1.62E-05  4.83E-05  8.19E-07  1.27E-05  2.88E-04  4.73E-03
F7  5.78E-06  1.09E-02  4.38E-03  1.33E-04  1.23E-04  2.43E-04
F8  -6978.02  -3112.81  -3521.99  -5478.15  -6205.49  -5645.51
F9  -2.83E-12  10.88  18.24  5.32  9.37E-02  1.43E-10
F10  1.29E-06  1.55E-02  3.74E-01  1.50E-04  7.17E-06  2.33E-06
F11  5.06E-12  1.97E-01  3.45E-01  2.18E-02  6.64E-09  2.95E-09
F12  1.67E-06  8.58E-04  25.94  2.67E-05  8.61E-04  4.20E-05
F13  6.29E-06  3.49E-03  5.79E-03  3.45E-05  7.14E-05  1.32E-05
F14  0.998  0.9821  1.3282  0.9978  1.3979  1.0613
F15  3.10E-04  7.82E-04  8.89E-04  3.38E-04  3.20E-04  3.43E-04
F16  -1.0316  -1.0316  -1.0316  -1.0316  -1.0316  -1.0018
F17  0.39789  0.3983  0.3982  0.3964  0.3977  0.4121
F18  3  3  3  3  3.00012  3.35123
F19  -3.8625  -3.8628  -3.8628  -3.8643  -3.8662  -3.8508
F20  -3.3216  -3.2198  -3.2187  -3.1892  -3.1718  -3.0714
F21  -10.016  -9.751  -8.362  -10.015  -8.681  -3.237
F22  -10.3985  -9.7201  -6.7462  -5.1766  -8.5914  -4.3017
F23  -9.5311  -8.8172  -3.6639  -7.3814  -7.9204  -4.3954
"""
PRINTED_BEST_TSV = """
F1  1.02E-12  2.81E-05  1.11E-09  4.49E-10  1.85E-10  8.50E-11
F2  5.09E-08  5.81E-05  1.37E-05  3.79E-06  1.07E-05  7.77E-06
F3  7.14E-12  2.16E-02  1.57E-07  2.82E-09  6.91E-10  1.58E-09
F4  5.19E-08  2.02E-02  4.13E-05  1.99E-05  6.42E-06  2.04E-06
F5  9.95E-05  6.10  2.64E-03  1.70E-03  1.91E-03  5.80E-04
F6  1.46E-05  1.94E-05  5.89E-10  6.19E-06  7.20E-05  1.16E-04
F7  2.26E-06  8.91E-03  3.67E-03  6.99E-05  6.77E-06  9.07E-06
F8  -12564.63  -6979.09  -5614.97  -8274.44  -12341.18  -8803.05
F9  6.68E-13  7.31  7.96  7.99  3.91E-09  1.24E-10
F10  4.15E-07  7.25E-03  3.12E-05  1.31E-05  4.06E-05  1.37E-06
F11  1.36E-12  1.16E-01  1.38E-01  1.40E-08  1.27E-10  2.07E-10
F12  1.01E-07  1.29E-06  4.51E-01  6.99E-06  1.51E-06  1.85E-06
F13  5.67E-06  2.08E-05  1.74E-5  1.66E-05  2.82E-05  5.96E-06
F14  0.998  0.998  0.998  0.998  0.998  0.99811
F15  3.02E-04  7.68E-03  1.22E-03  3.08E-04  3.09E-04  3.18E-04
F16  -1.0316  -1.0316  -1.0316  -1.0316  -1.0316  -1.0247
F17  0.39789  0.39789  0.39789  0.39789  0.39791  0.40085
F18  3  3  3  3  3  3.0436
F19  -3.8615  -3.8628  -3.8628  -3.8628  -3.8628  -3.8481
F20  -3.3205  -3.3220  -3.3220  -3.3220  -3.3213  -3.0163
F21  -10.1532  -10.1532  -10.1532  -10.1532  -10.11091  -4.1752
F22  -10.4029  -10.4029  -10.4029  -10.3991  -10.3893  -5.3595
F23  -10.5363  -10.5364  -5.1756  -10.5361  -10.4548  -7.5633
"""
PRINTED_WORST_TSV = """
F1  3.05E-12  2.25E-04  3.16E-09  2.78E-09  4.17E-10  3.92E-10
F2  2.38E-07  1.79E-02  7.43E-01  6.81E-06  1.17E-05  1.37E-05
F3  1.09E-10  6.81E-02  1.02E-05  9.92E-09  4.38E-09  3.08E-09
F4  8.23E-07  3.28E-02  5.52E-04  3.21E-05  8.43E-06  4.34E-06
F5  1.12E-03  14.90  9.61  5.11E-03  1.64E-02  3.05E-03
F6  2.98E-05  1.51E-04  3.01E-06  1.56E-05  3.05E-04  7.72E-03
F7  9.21E-06  1.77E-02  5.11E-02  1.77E-03  3.94E-04  2.16E-04
F8  -4182.9987  -1925.8472  -2044.2853  -3970.2836  -2213.5056  -4053.0627
F9  6.10E-12  12.08  30.84  13.98  3.75  1.62E-10
F10  1.29E-06  3.10E-2  1.12  1.01E-2  7.17E-05  3.13E-06
F11  9.72E-12  1.97E-01  3.45E-01  2.19E-01  2.84E-08  2.95E-09
F12  8.51E-06  2.14E-02  97.07  5.37E-05  1.75E-04  1.09E-04
F13  9.69E-06  2.60E-01  1.12E-02  7.48E-04  7.07E-04  4.60E-05
F14  0.998  1.992  1.992  3.9683  0.9979  1.2267
F15  3.10E-04  9.90E-04  1.00E-03  3.38E-04  2.19E-03  3.53E-04
F16  -1.0316  -1.0316  -1.0316  -1.0316  -1.0316  -1.0247
F17  0.39789  0.3997  0.3987  0.3904  0.39721  0.4254
F18  3  3  3  3  3.0004  3.6114
F19  -3.8627  -3.8628  -3.8628  -3.8628  -3.7486  -3.8014
F20  -3.3219  -2.6829  -3.2031  -3.1462  -3.0634  -2.8063
F21  -5.0551  -2.6829  -5.055  -2.6829  -2.6295  -1.9851
F22  -10.3451  -5.1288  -2.7519  -1.8376  -3.7234  -2.3182
F23  -5.5386  -5.1756  -2.4217  -1.6766  -2.4273  -2.0791
"""


def _parse(tsv: str) -> dict[str, dict[str, str]]:
    rows = (line.split() for line in tsv.strip().splitlines())
    return {row[0]: dict(zip(ALGORITHMS, row[1:], strict=True)) for row in rows}


PRINTED_MEAN = _parse(PRINTED_MEAN_TSV)
PRINTED_BEST = _parse(PRINTED_BEST_TSV)
PRINTED_WORST = _parse(PRINTED_WORST_TSV)


def printed_half_unit(text: str) -> float:
    """Half a unit of the last printed digit: how far a printed number may lie from its value."""
    mantissa, _, exponent = text.upper().partition("E")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (-decimals) * 10.0 ** int(exponent or 0)


def below_minimum(text: str, minimum: float) -> bool:
    """True if a printed value is below a known global minimum even allowing for its rounding."""
    return float(text) + printed_half_unit(text) < minimum - 1e-12 * max(1.0, abs(minimum))


def ordering_errors() -> list[str]:
    """Printed best/mean/worst triples that contradict best <= mean <= worst beyond rounding."""
    errors = []
    for function, means in PRINTED_MEAN.items():
        for algorithm in ALGORITHMS:
            best, mean, worst = PRINTED_BEST[function][algorithm], means[algorithm], PRINTED_WORST[function][algorithm]
            slack = printed_half_unit(best) + printed_half_unit(mean) + printed_half_unit(worst)
            values = [float(best), float(mean), float(worst)]
            if values[0] > values[1] + slack or values[1] > values[2] + slack or values[0] > values[2] + slack:
                errors.append(f"{function} {algorithm}: best {best}, mean {mean}, worst {worst}")
    return errors


def _printed(text: str, minimum: float) -> str:
    return f"{text} (!)" if below_minimum(text, minimum) else text


def benchmark_table(results: Results) -> tuple[list[str], int, int, int]:
    """ALO and OCALO on the plain functions, ours (mean, best) beside tables 2 and 3; returns the
    markdown lines, on how many functions our OCALO mean beats our ALO mean, of how many, and the
    same count in table 2."""
    lines = [
        "| F | ALO mean (ours) | OCALO mean (ours) | ALO best (ours) | OCALO best (ours) "
        "| ALO mean (seed) | OCALO mean (seed) | ALO best (seed) | OCALO best (seed) |",
        "|" + "---|" * 9,
    ]
    for bench in BENCHMARKS:
        if (bench.name, "alo", PLAIN) not in results or (bench.name, "ocalo", PLAIN) not in results:
            continue
        alo, ocalo = results[bench.name, "alo", PLAIN], results[bench.name, "ocalo", PLAIN]
        mean, best = PRINTED_MEAN[bench.name], PRINTED_BEST[bench.name]
        printed = [_printed(t[a], bench.minimum) for t in (mean, best) for a in ("ALO", "OCALO")]
        ours = [fmt_g(alo.mean()), fmt_g(ocalo.mean()), fmt_g(alo.min()), fmt_g(ocalo.min())]
        lines.append(f"| {bench.name} | " + " | ".join(ours + printed) + " |")
    won, total = wins(results, "ocalo", "alo", PLAIN)
    return lines, won, total, printed_wins()


def printed_wins() -> int:
    """On how many functions table 2 prints OCALO's mean below ALO's."""
    return sum(float(row["OCALO"]) < float(row["ALO"]) for row in PRINTED_MEAN.values())


def impossible_printed() -> list[str]:
    """Every printed value of tables 2-4 below its function's known global minimum."""
    found = []
    tables = (("mean", PRINTED_MEAN), ("best", PRINTED_BEST), ("worst", PRINTED_WORST))
    for bench in BENCHMARKS:
        for label, table in tables:
            for algorithm, text in table[bench.name].items():
                if below_minimum(text, bench.minimum):
                    found.append(f"{bench.name} {algorithm} {label} {text} < known minimum {bench.minimum:.10g}")
    return found


def ordering_differences(results: Results, form: str = PLAIN) -> list[str]:
    """Functions where our ALO/OCALO ordering (by mean) differs from table 2's."""
    lines = []
    for bench in BENCHMARKS:
        if (bench.name, "alo", form) not in results or (bench.name, "ocalo", form) not in results:
            continue
        ours = results[bench.name, "ocalo", form].mean() < results[bench.name, "alo", form].mean()
        printed = PRINTED_MEAN[bench.name]
        seed = float(printed["OCALO"]) < float(printed["ALO"])
        if ours != seed:
            winner = {True: "OCALO", False: "ALO"}
            lines.append(f"{bench.name}: ours {winner[ours]} better, seed 002 {winner[seed]} better")
    return lines


def benchmark_report(results: Results, runs: int) -> str:
    """Markdown: our ALO/OCALO beside tables 2 and 3, the printed values no algorithm can reach,
    the printed triples out of order, and where our ordering differs from the paper's."""
    lines, won, total, seed_won = benchmark_table(results)
    out = [
        f"ALO and OCALO, ours (mean and best over {runs} runs, plain form) beside seed 002's tables 2 and 3; "
        "(!) marks a printed value below the function's known global minimum.",
        "",
        *lines,
        "",
        f"OCALO beats ALO on {won} of {total} (mean over {runs} runs, plain form); "
        f"in seed 002's table 2, OCALO beats ALO on {seed_won} of {len(PRINTED_MEAN)}.",
    ]
    for form in forms_of(results):
        if form != PLAIN and wins(results, "ocalo", "alo", form)[1]:
            f_won, f_total = wins(results, "ocalo", "alo", form)
            out[-1] += f" {form.capitalize()}: OCALO beats ALO on {f_won} of {f_total}."
    out += ["", "Printed values of seed 002's tables 2-4 below the known global minimum (impossible, allowing for "
            "rounding):", "", *[f"- {line}" for line in impossible_printed()], "",
            "Printed best/mean/worst triples out of order (best <= mean <= worst must hold):", "",
            *[f"- {line}" for line in ordering_errors()]]
    differences = ordering_differences(results)
    if differences:
        out += ["", "Where our ALO/OCALO ordering (mean, plain form) differs from seed 002's table 2:", "",
                *[f"- {line}" for line in differences]]
    return "\n".join(out) + "\n"


# -- the command's and the page's rerun ---------------------------------------------------------------

PAPER_RUNS = 50  # section 3: "the average of the results of 50 iterations" (runs), population 50, 300 iterations
SMALL = {"runs": 2, "population": 50, "iterations": 50}
PAPER = {"runs": PAPER_RUNS, "population": 50, "iterations": 300}
METHODS_RUN = ("alo", "ocalo")
WORKERS = 2


def settings(budget: Budget) -> dict[str, int]:
    """Runs, population and iterations at a budget (N: the paper's runs and population, N iterations)."""
    if budget.iterations is not None:
        return {**PAPER, "iterations": budget.iterations}
    return PAPER if budget.name == PAPER_NAME else SMALL


def run_count(budget: Budget) -> int:
    """How many optimiser runs ``rerun`` makes (its progress calls)."""
    names = [b.name for b in BENCHMARKS]
    return len(tasks_for(names, METHODS_RUN, settings(budget)["runs"], seed=0, population=1, iterations=1,
                         forms=(PLAIN, SHIFTED)))


def rerun(budget: Budget, progress: Progress = no_progress, seed: int = 0) -> Results:
    """ALO and OCALO on F1-F23 (plain) and on the shifted F1-F7, F9-F13, at the budget."""
    s = settings(budget)
    return run_all([b.name for b in BENCHMARKS], METHODS_RUN, s["runs"], seed=seed, population=s["population"],
                   iterations=s["iterations"], workers=WORKERS, forms=(PLAIN, SHIFTED),
                   progress=lambda n: progress("benchmark run"))


def _impossible_rows() -> list[Verdict]:
    rows = []
    for label, printed in (("table 2 (mean)", PRINTED_MEAN), ("table 3 (best)", PRINTED_BEST),
                           ("table 4 (worst)", PRINTED_WORST)):
        for bench in BENCHMARKS:
            rows += [Verdict(label, f"{bench.name} ({bench.title}), {algorithm}", text, f"minimum {bench.minimum:.10g}",
                             IMPOSSIBLE, "below the function's known global minimum beyond the rounding of its "
                             "printed digits: no algorithm can reach it")
                     for algorithm, text in printed[bench.name].items() if below_minimum(text, bench.minimum)]
    for line in ordering_errors():
        function, _, triple = line.partition(": ")
        rows.append(Verdict("tables 2-4", f"{function} best / mean / worst", triple, "-", IMPOSSIBLE,
                            "best <= mean <= worst must hold for any set of runs"))
    return rows


def _claim_rows(results: Results, runs: int, budget_words: str) -> list[Verdict]:
    """Table 2's ordering of OCALO and ALO, function by function, against ours (plain and shifted)."""
    rows = []
    for bench in BENCHMARKS:
        printed = PRINTED_MEAN[bench.name]
        seed_says = float(printed["OCALO"]) < float(printed["ALO"])
        alo, ocalo = results[bench.name, "alo", PLAIN].mean(), results[bench.name, "ocalo", PLAIN].mean()
        ours_says = ocalo < alo
        why = f"means over {runs} runs, {budget_words}"
        shifted = (bench.name, "ocalo", SHIFTED) in results
        if shifted:
            s_alo, s_ocalo = results[bench.name, "alo", SHIFTED].mean(), results[bench.name, "ocalo", SHIFTED].mean()
            why += f"; shifted: OCALO {fmt_g(s_ocalo)}, ALO {fmt_g(s_alo)}"
            if ours_says and s_ocalo >= s_alo:
                why += " (OCALO's lead comes from its pull to the origin, where the plain minimum is)"
        sign = {True: "<", False: ">="}
        rows.append(Verdict("table 2 (mean)", f"{bench.name}: OCALO {sign[seed_says]} ALO",
                            f"{printed['OCALO']} {sign[seed_says]} {printed['ALO']}",
                            f"{fmt_g(ocalo)} {sign[ours_says]} {fmt_g(alo)}",
                            REPRODUCED if ours_says == seed_says else DIFFERS, why))
    return rows


def benchmark_verdicts(results: Results, budget: Budget) -> list[Verdict]:
    """Every printed value no run can give, then table 2's OCALO/ALO ordering against ours."""
    s = settings(budget)
    words = f"population {s['population']} x {s['iterations']} iterations (paper: 50 runs of 50 x 300)"
    return _impossible_rows() + _claim_rows(results, s["runs"], words)


def summary_note(results: Results) -> str:
    """The benchmark's verdict in words: how often OCALO beats ALO, plain and shifted, and why."""
    won, total = wins(results, "ocalo", "alo", PLAIN)
    s_won, s_total = wins(results, "ocalo", "alo", SHIFTED)
    f1 = {(m, form): fmt_g(results["F1", m, form].mean()) for m in METHODS_RUN for form in (PLAIN, SHIFTED)}
    return (f"benchmark: by our means OCALO beats ALO on {won} of {total} functions (table 2: {printed_wins()} of "
            f"{len(PRINTED_MEAN)}); with the minima moved off the origin (shifted form) on {s_won} of {s_total}. "
            f"OCALO's update pulls every ant toward the origin (its cosine factors end at 0.01 of the step): where the "
            f"minimum is there it lands on it, elsewhere the pull leads away from it. F1's mean, OCALO "
            f"{f1['ocalo', PLAIN]} at the origin and {f1['ocalo', SHIFTED]} shifted; ALO {f1['alo', PLAIN]} and "
            f"{f1['alo', SHIFTED]}")
