"""python -m tools.seeds SEED and python -m tools.seeds.seedNNN (tools/seeds/__main__.py, command.py) and
the report they print (tools/seeds/report.py)."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from tools.seeds import __main__ as cli
from tools.seeds import command, seed001, seed003
from tools.seeds.papers import PAPERS
from tools.seeds.report import (
    DIFFERS,
    FITTED,
    IMPOSSIBLE,
    PAPER_BUDGET,
    REPRODUCED,
    SMALL_BUDGET,
    Budget,
    SeedReport,
    Table,
    Verdict,
    markdown_verdicts,
    num,
    parse_budget,
    text,
)


def _report(verdicts: tuple[Verdict, ...]) -> SeedReport[None]:
    return SeedReport("009", "a paper", "small: none", ("paper loop: no firmware delay",), verdicts, None,
                      (Table("twin:", ("a", "b"), (("x", "1.00"),)),), ("a note",))


ROWS = (Verdict("table 1", "rise s", "10", "10.00", REPRODUCED, "re-run"),
        Verdict("table 1", "settling s", "0.3", "120.0", IMPOSSIBLE, "before the dead time"),
        Verdict("table 2", "max C", "106", "106.7", FITTED, "the range was bisected to it"))


def test_budgets_parse_and_bad_ones_name_the_choices() -> None:
    assert parse_budget("small") == SMALL_BUDGET and parse_budget("paper") == PAPER_BUDGET
    assert parse_budget("40") == Budget("iterations", 40) and str(parse_budget("40")) == "40 iterations"
    for bad in ("2", "-5", "huge", "1e3"):
        with pytest.raises(argparse.ArgumentTypeError, match="small, paper or a number"):
            parse_budget(bad)


def test_a_verdict_is_one_of_four() -> None:
    with pytest.raises(ValueError, match="verdict must be one of"):
        Verdict("t", "q", "1", "1", "close enough", "")


def test_text_puts_each_printed_number_beside_ours_with_its_verdict_and_loop() -> None:
    out = text(_report(ROWS))
    assert out.startswith("Seed 009: a paper\n") and "paper loop: no firmware delay" in out
    line = next(line for line in out.splitlines() if line.startswith("table 1") and "settling" in line)
    assert "0.3" in line and "120.0" in line and line.endswith("impossible: before the dead time")
    assert "verdicts: 1 reproduced, 1 fitted, 1 impossible (of 3)" in out
    assert "twin:\na  b\nx  1.00" in out and "a note" in out


def test_markdown_verdicts_count_the_verdicts() -> None:
    md = markdown_verdicts(_report(ROWS))
    assert "| table 2 | max C | 106 | 106.7 | fitted | the range was bisected to it |" in md
    assert md.endswith("Verdicts: 1 reproduced, 1 fitted, 1 impossible (of 3).")
    assert num(None) == "-" and num(2e7) == "diverges" and num(1.234, 1) == "1.2"


def test_every_paper_reports_and_counts_its_steps() -> None:
    for seed, module in PAPERS.items():
        assert callable(module.report) and module.steps(SMALL_BUDGET) > 0, seed
    assert PAPERS["002"].steps(PAPER_BUDGET) > PAPERS["002"].steps(SMALL_BUDGET)  # 50 runs of the benchmark


@pytest.mark.parametrize(("argv", "flag"), [(["001", "--check"], "--check"), (["--budget", "small"], "--budget"),
                                            (["007"], "seed"), (["001", "--budget", "lots"], "--budget")])
def test_bad_flags_are_one_line_and_exit_2(argv, flag, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and flag in err


@pytest.mark.slow
def test_seed_003_prints_its_table_beside_the_papers_with_one_progress_step_each(capsys) -> None:
    labels: list[str] = []
    report = seed003.report(SMALL_BUDGET, labels.append)
    assert len(labels) == seed003.steps(SMALL_BUDGET)
    verdicts = {r.verdict for r in report.verdicts}
    assert verdicts <= {REPRODUCED, DIFFERS, IMPOSSIBLE}
    assert cli.main(["003"]) == 0
    out = capsys.readouterr().out
    assert "table 1, MSDI fig. 4a  rise s" in out and "impossible:" in out and "no firmware delay" in out


@pytest.mark.slow
def test_python_m_seed_module_is_the_same_command() -> None:
    done = subprocess.run([sys.executable, "-m", "tools.seeds.seed001", "--budget", "small"], capture_output=True,
                          text=True, timeout=3600, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("Seed 001: Fuzzy-PID nozzle temperature control")
    assert "fuzzy-PID settles faster than the PID" in done.stdout
    assert "seed 001" in done.stderr  # the progress bar


@pytest.mark.slow
def test_seed_001_judges_the_claim_and_runs_the_literal_reading_at_a_scale_that_fits() -> None:
    """In the stable reading the fuzzy-PID settles slower than ZN's PID: the claim differs; the
    literal reading at scaling ZN / 1.5 settles in both loops where the paper's scaling 1 diverges."""
    report = seed001.report(SMALL_BUDGET)
    claim = next(r for r in report.verdicts if r.quantity == "fuzzy-PID settles faster than the PID")
    assert claim.verdict == DIFFERS and claim.claim and "opposite" in claim.why
    fitted = [r for r in report.result.responses if r.controller == seed001.FITTED_LITERAL_NAME]
    assert len(fitted) == 2 and all(r.stable for r in fitted)
    default = next(note for note in report.notes if note.startswith("`twin-sim --firmware fuzzy_pid"))
    assert "halts at" in default and "--gains 0.978,0.0298,8.02" in default  # ZN in counts, from the model


def test_main_for_parses_the_budget_and_runs(monkeypatch, capsys) -> None:
    seen = []

    def fake_report(budget, progress):
        seen.append(budget)
        progress("one")
        return _report(ROWS)

    assert command.main_for("009", fake_report, lambda budget: 1, ["--budget", "paper"]) == 0
    assert seen == [PAPER_BUDGET] and capsys.readouterr().out.startswith("Seed 009: a paper")
