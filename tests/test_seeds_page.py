"""docs/seeds.md (tools/seeds/page.py, python -m tools.seeds): complete, current, and checked by --check."""

from __future__ import annotations

import pytest

from tools.seeds import __main__ as cli
from tools.seeds import page, seed002
from tools.tuning.benchfuncs import BY_NAME
from tools.validation.doc_compare import compare_docs



@pytest.fixture(scope="module")
def committed() -> dict[str, str]:
    return page.sections(page.DOC.read_text())


@pytest.fixture(scope="module")
def fresh() -> dict[str, str]:
    """Every section re-rendered: about a minute of one core (measured: the whole page in 60 s here)."""
    return page.sections(page.render())


def test_every_seed_has_a_section(committed):
    assert list(committed) == list(page.SECTIONS) == ["000", "001", "002", "003", "004"]
    assert "pending" not in page.DOC.read_text()  # seed 000 has landed: no section waits for it


@pytest.mark.parametrize("seed", list(page.SECTIONS))
def test_sections_are_current(committed, fresh, seed):
    """Verdicts, words and integers exactly, decimals within doc_compare's tolerance (5 % or 3 steps of
    the last digit): the loops are float simulations and fits (seed 000's ANFIS networks are trained
    through BLAS) whose last digits may move with the CPU. Checked: the page rendered with
    OPENBLAS_CORETYPE=Sandybridge (all seeds) and Haswell (seeds 000, 002) matches the one committed from
    this machine's default (AVX-512) kernel."""
    mismatches = compare_docs(fresh[seed], committed[seed])
    assert not mismatches, "\n".join(map(str, mismatches)) + f"\nregenerate with {page.COMMAND}"


def test_impossible_numbers_are_named_on_the_page(committed):
    assert "does not move before" in committed["001"]  # settling before the dead time
    assert "known global minimum" in committed["002"] and "F19 (Hartmann 3)" in committed["002"]
    assert "Kp above the model's ultimate gain" in committed["003"]


def test_below_minima_are_below_the_known_minima():
    rows = page.below_minima()
    assert rows
    for _, function, _, printed, _ in rows:
        name = function.split()[0]
        assert float(printed) + seed002.printed_half_unit(printed) < BY_NAME[name].minimum
    # the printed Rastrigin mean -2.83E-12 (its minimum is 0) is one of them
    assert ["table 2 (mean)", "F9 (Rastrigin)", "OCALO", "-2.83E-12", "0"] in rows


def test_sections_cut_a_page_at_its_seed_headings():
    text = "# title\n\nintro\n\n## Seed 001: a\n\nx 1.5\n\n## Seed 004: b\n\ny\n"
    assert page.sections(text) == {"001": "## Seed 001: a\n\nx 1.5", "004": "## Seed 004: b\n\ny"}


def _cheap_page(monkeypatch, value: str) -> None:
    monkeypatch.setattr(page, "SECTIONS", {"001": lambda: f"## Seed 001: t\n\n| a | {value} |"})


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
    monkeypatch.setattr(page, "SECTIONS", {"001": lambda: "## Seed 001: a\n\nold", "003": lambda: "## Seed 003: b\n\nold"})
    assert cli.main(["--out", str(out)]) == 0
    monkeypatch.setitem(page.SECTIONS, "003", lambda: "## Seed 003: b\n\nnew")
    assert cli.main(["--seeds", "003", "--out", str(out)]) == 0
    assert page.sections(out.read_text()) == {"001": "## Seed 001: a\n\nold", "003": "## Seed 003: b\n\nnew"}
