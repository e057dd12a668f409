"""twin-tune --from-log on every capture: where twin-fit fits a log, twin-tune tunes it (the rules and the
twin's autotune, on the fit alone: --spread 0, as twin-fit --fit-only fits it) and prints the very
parameters twin-fit prints; where twin-fit refuses a log, twin-tune refuses it too, with one line; where
the fit is degenerate, twin-tune keeps the printer's gains (no plant to beat them on) or has no answer."""

from __future__ import annotations

import itertools

import pytest

from tools.cli import fit as fit_cli
from tools.cli import tune as tune_cli
from tools.tuning.defaults import EXIT_NO_MODEL


@pytest.mark.slow
@pytest.mark.each_hardware_log("*", exclude=["README.md"])
def test_twin_tune_tunes_what_twin_fit_fits(capsys, hardware_log):
    path = str(hardware_log)
    fitted = fit_cli.main([path, "--fit-only"])
    fit_out = capsys.readouterr().out
    tuned = tune_cli.main(["--from-log", path, "--method", "rules", "--proof", "0", "--spread", "0", "--plot", "none"])
    captured = capsys.readouterr()
    if fitted == EXIT_NO_MODEL:  # a degenerate fit: no plant; the printer's gains kept where the log states them
        assert tuned in (0, EXIT_NO_MODEL), captured.err
        assert ("answer: keep your gains (" if tuned == 0 else "no answer: ") in captured.out
        return
    if fitted != 0:
        assert tuned == 2 and captured.err.count("\n") == 1, (fitted, captured.err)
        return
    assert tuned == 0, captured.err  # unproven (--proof 0): an answer, never "proven"
    assert "proven on" not in captured.out and "not proven (--proof 0)" in captured.out
    lines = captured.out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("plant: ")) + 1
    params = list(itertools.takewhile(lambda line: line.startswith("  "), lines[start:]))
    assert params and set(params) <= set(fit_out.splitlines()), (params, fit_out)
