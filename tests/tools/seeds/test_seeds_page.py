"""docs/seeds.md (tools/docs/seeds_page.py, python -m tools.seeds): complete, current, and checked by --check."""

from __future__ import annotations

import pytest

from tools.seeds import __main__ as cli
from tools.docs import seeds_page as page
from tools.seeds.report import FITTED, VERDICTS
from tools.validation.doc_compare import compare_docs


@pytest.fixture(scope="module")
def committed() -> dict[str, str]:
    return page.sections(page.DOC.read_text())


@pytest.fixture(scope="module")
def fresh() -> dict[str, str]:
    """Every section re-rendered at the small budget: a few minutes of one core."""
    return page.sections(page.render())


def test_every_seed_has_a_section(committed):
    assert list(committed) == list(page.SECTIONS) == ["000", "001", "002", "003", "004"]
    assert "pending" not in page.DOC.read_text()


@pytest.mark.slow
@pytest.mark.parametrize("seed", list(page.SECTIONS))
def test_sections_are_current(committed, fresh, seed):
    """Verdicts, words and integers exactly, decimals within doc_compare's tolerance (5 % or 3 steps of
    the last digit): the loops are float simulations and fits (seed 000's ANFIS networks are trained
    through BLAS) whose last digits may move with the CPU. A verdict or a count of verdicts that moves
    is a finding, not noise: they are words and integers."""
    mismatches = compare_docs(fresh[seed], committed[seed])
    assert not mismatches, "\n".join(map(str, mismatches)) + f"\nregenerate with {page.COMMAND}"


def test_every_section_judges_its_numbers_and_says_where_they_come_from(committed):
    for seed, text in committed.items():
        assert "| experiment | quantity | printed | ours | verdict | why |" in text, seed
        assert "Where each number comes from:" in text and "In words:" in text, seed
        assert "firmware delay" in text or "firmware twin only" in text, seed  # which loop, with or without it
        table = text.split("| experiment | quantity | printed | ours | verdict | why |\n|---|---|---|---|---|---|\n")[1]
        rows = table.split("\n\n")[0].splitlines()
        assert rows and {row.split(" | ")[4] for row in rows} <= set(VERDICTS), seed


def test_the_page_says_what_contradicts_the_papers(committed):
    """The findings the page must state in words, whatever the digits."""
    assert "does not move before" in committed["001"]  # settling before the dead time
    assert "The paper's claim 'fuzzy-PID settles faster than the PID'" in committed["001"]
    assert "the opposite of the paper's claim" in committed["001"]
    assert "known global minimum" in committed["002"] and "F19 (Hartmann 3)" in committed["002"]
    assert "pulls every ant toward the origin" in committed["002"]
    assert "their readings are the same until then" in committed["002"]  # why the Marlin twin halts them all
    assert "Kp above the model's ultimate gain" in committed["003"]
    fits = [line for line in committed["004"].splitlines() if line.startswith("| section 5") and f"| {FITTED} |" in line]
    assert len(fits) >= 3  # bed rise (its loss), bed settling (its range), extruder steady maximum (its sensor)
    assert "| pso | overshoot_pct | 78.62 | 78.58 | differs |" in committed["000"]  # not within the printed rounding


def test_sections_cut_a_page_at_its_seed_headings():
    text = "# title\n\nintro\n\n## Seed 001: a\n\nx 1.5\n\n## Seed 004: b\n\ny\n"
    assert page.sections(text) == {"001": "## Seed 001: a\n\nx 1.5", "004": "## Seed 004: b\n\ny"}


def _cheap_page(monkeypatch, value: str) -> None:
    monkeypatch.setattr(page, "SECTIONS", {"001": lambda progress: f"## Seed 001: t\n\n| a | {value} |"})


def test_check_passes_within_tolerance_and_fails_beyond(monkeypatch, tmp_path, capsys):
    out = tmp_path / "seeds.md"
    _cheap_page(monkeypatch, "10.00")
    assert cli.main(["--out", str(out)]) == 0
    _cheap_page(monkeypatch, "10.20")  # 2 %: another machine's rounding
    assert cli.main(["--check", "--out", str(out)]) == 0
    _cheap_page(monkeypatch, "11.00")  # 10 %: a change
    assert cli.main(["--check", "--out", str(out)]) == 1
    assert "11.00 against 10.00" in capsys.readouterr().out


def test_bad_flags_give_one_line(tmp_path, capsys):
    assert cli.main(["--seeds", "007"]) == 2
    assert cli.main(["--check", "--out", str(tmp_path / "missing.md")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("tools.seeds: --seeds") and err[1].startswith("tools.seeds: --out")


def test_writing_a_subset_keeps_the_other_sections(monkeypatch, tmp_path):
    out = tmp_path / "seeds.md"
    monkeypatch.setattr(page, "SECTIONS", {"001": lambda p: "## Seed 001: a\n\nold", "003": lambda p: "## Seed 003: b\n\nold"})
    assert cli.main(["--out", str(out)]) == 0
    monkeypatch.setitem(page.SECTIONS, "003", lambda p: "## Seed 003: b\n\nnew")
    assert cli.main(["--seeds", "003", "--out", str(out)]) == 0
    assert page.sections(out.read_text()) == {"001": "## Seed 001: a\n\nold", "003": "## Seed 003: b\n\nnew"}

