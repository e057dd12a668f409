"""One answer per capture: a verdict wherever the printer's gains are known (exit 0), exit 3 only
with neither a model nor gains; the bed capture a degenerate fit once got refused on now gets a verdict;
under "keep your gains" the closest candidate is an option with its command; twin-fit prints twin-tune's
very answer lines."""

from __future__ import annotations

import contextlib
import json
import re
from types import SimpleNamespace

import numpy as np
import pytest

from tools.cli import fit, tune
from tools.tuning.answer import CANNOT_MODEL, verdict_lines
from tools.tuning.defaults import EXIT_ANSWER, EXIT_NO_MODEL, EXIT_UNSAFE
from tools.tuning.ensemble import Ensemble, Member
from tools.tuning.gains import Gains
from tools.tuning.problems import build_problem, preset_source
from tools.tuning.proof import ProofRow
from tools.tuning.reference import PrinterGains
from tools.tuning.tuner import Proven
from tools.tuning.verdict import judge

ARTILLERY_BED = "m303_bed_artillery_genius_pro_S60_configs641.txt"
PARTIAL = "m303_hotend_S250_trace_marlin8081_partial.txt"  # one printed cycle: no plant replays it
COLLECTION = "klipper_pid_calibrate_results_collection.txt"
QUICK = ["--budget", "90", "--proof", "2"]


def _run(capsys, main, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _answer(out: str) -> list[str]:
    """The answer's lines: from 'answer: ' to twin-tune's table of candidates (twin-fit's end)."""
    lines = out.splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith("answer: "))
    end = next((k for k in range(start, len(lines)) if lines[k].startswith("candidates on the ")), len(lines))
    return lines[start:end]


@pytest.mark.parametrize("main", [tune.main, fit.main])
def test_help_states_the_exit_codes(capsys, main):
    with contextlib.suppress(SystemExit):  # twin-fit's --help exits, twin-tune's returns 0
        main(["--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "0 a verdict: new gains that beat yours" in out
    assert "2 bad input" in out and "3 neither a model nor a reference" in out


def _row(member: str, method: str, params, overshoot: float, hold: float, chatter: float, cost: float) -> ProofRow:
    return ProofRow(member, method, np.asarray(params, float), 2, 0, (overshoot, overshoot), (100.0, 100.0),
                    (hold, hold), (chatter, chatter), (cost, cost))


def test_keep_your_gains_comes_with_the_closest_candidate_as_an_option_and_its_command():
    """The bed capture's case: the runner-up ties on hold on one plant, overshoots far less and chatters
    less, and misses on another plant's hold: keep, and the user sees that trade and how to take it."""
    problem = build_problem(preset_source("bed", 0), 60.0)
    members = ("fopdt", "sopdt")
    ensemble = Ensemble(tuple(Member(m, (), 1.0, k) for k, m in enumerate(members)), "mean_std", kind="plants")
    yours = [_row(m, "yours", (22.17, 1.36, 241.3), 2.8, 0.155, 0.07, 300.0) for m in members]
    other = [_row("fopdt", "de #2", (30, 1.5, 300), 0.5, 0.15, 0.02, 250.0),
             _row("sopdt", "de #2", (30, 1.5, 300), 0.7, 0.211, 0.02, 250.0)]
    verdict = judge(other + yours, "yours", ["de #2"], ensemble)
    proof = Proven(verdict, other + yours, None, SimpleNamespace(method="yours"), "")  # type: ignore[arg-type]
    status, lines = verdict_lines(problem, proof, True, None)
    assert status == EXIT_ANSWER
    assert lines[0] == ("answer: keep your gains: nothing beats them on all plants: the closest, de #2, misses on "
                        "sopdt: hold 0.211 C > 0.191 C")
    assert lines[1] == ("option: de #2 Kp 30 Ki 1.5 Kd 300: overshoot 2.8 -> 0.7 C, hold 0.15 -> 0.21 C, duty chatter "
                        "-71 %, on all 2 plants (worst seed); the worse hold buys overshoot 2.8 -> 0.7 C, duty chatter "
                        "-71 %, objective 300 -> 250 s (heat-up time, overshoot beyond 3 C, hold, chatter); not the "
                        "answer: it misses on sopdt: hold 0.211 C > 0.191 C. To take it anyway:")
    assert lines[2:5] == ["  Marlin (proven on the Marlin loop; send, then M500 to keep it):", "    M304 P30 I1.5 D300",
                          "    M500"]


@pytest.mark.slow
def test_the_bed_capture_a_degenerate_fit_got_refused_on_gets_a_verdict(capsys, tmp_path, hardware_logs):
    """three_node fits the Artillery bed's cycles as well as fopdt but identifies none of its lags: it was a
    member, ranked best, and the tune was refused ("the fit cannot support a tune"). Now it is dropped with
    that reason and the tune answers, exit 0."""
    answer = tmp_path / "answer.json"
    code, out, err = _run(capsys, tune.main, "--from-log", str(hardware_logs / ARTILLERY_BED), *QUICK, "--plot", "none",
                          "--json", str(answer), "--progress", "lines")
    assert code == 0, err
    assert re.search(r"^  dropped three_node: degenerate: the data identify none of three_node's lags", out, re.M)
    document = json.loads(answer.read_text())
    assert "three_node" not in {m["label"] for m in document["members"]}
    assert document["verdict"] in ("new gains", "keep your gains")
    lines = _answer(out)
    if document["verdict"] == "keep your gains":  # the closest candidate, not your own gains, as an option
        assert lines[1].startswith("option: ") and document["option"]["commands"][0].startswith("M304 P")
        assert document["option"]["kp"] != pytest.approx(22.17)
    else:
        assert document["commands"][0].startswith("M304 P")


@pytest.mark.slow
def test_a_capture_no_plant_replays_keeps_the_printers_gains_or_exits_3_without_them(capsys, tmp_path, hardware_logs):
    """It parsed fine, no plant both fits it and replays it: with the gains it printed, keep them (exit 0,
    and twin-fit says the same); without them, neither a model nor a reference: exit 3, one line."""
    code, out, err = _run(capsys, tune.main, "--from-log", str(hardware_logs / PARTIAL), *QUICK, "--plot", "none")
    assert code == EXIT_ANSWER and "Traceback" not in err, err
    lines = _answer(out)
    assert lines == [
        f"answer: keep your gains (Kp 15.65 Ki 1.42 Kd 42.96: the last Kp/Ki/Kd the capture printed): {CANNOT_MODEL}: "
        + lines[0].split(f"{CANNOT_MODEL}: ", 1)[1]]
    assert re.search(r": no plant both fits it and replays it: fopdt: .*; sopdt: .*; two_node: .*; three_node: ",
                     lines[0])
    code_fit, out_fit, _ = _run(capsys, fit.main, str(hardware_logs / PARTIAL), *QUICK)
    assert code_fit == EXIT_ANSWER and _answer(out_fit) == lines
    stripped = tmp_path / PARTIAL
    stripped.write_text("".join(line for line in (hardware_logs / PARTIAL).read_text().splitlines(keepends=True)
                                if "Kp:" not in line))
    code, out, err = _run(capsys, tune.main, "--from-log", str(stripped), *QUICK, "--plot", "none")
    assert code == EXIT_NO_MODEL and "no answer: " in out
    assert err.strip().splitlines()[-1].startswith("twin-tune: ") and "Traceback" not in err


@pytest.mark.slow
def test_twin_fit_and_twin_tune_print_the_same_answer(capsys, hardware_logs):
    """One answer per capture: twin-fit runs twin-tune's default tune (here both at --budget 90 --proof 2) and
    prints its very lines, gains and all."""
    log = str(hardware_logs / COLLECTION)
    code_tune, out_tune, err = _run(capsys, tune.main, "--from-log", log, "--segment", "0", *QUICK, "--plot", "none")
    assert code_tune == 0, err
    code_fit, out_fit, err = _run(capsys, fit.main, log, "--segment", "0", *QUICK)
    assert code_fit == code_tune, err
    answer = _answer(out_tune)
    assert _answer(out_fit) == answer
    assert re.search(r"pid_Kp|M30[14] ", "\n".join(answer))  # gains to paste: the answer's, or the option's


def test_gains_that_trip_on_a_plant_are_kept_where_they_are_the_printers_and_unsafe_otherwise():
    """Where the reference trips on a plant the log allows and nothing beats it: the printer's own gains are
    kept (exit 0: the twin cannot model the heater well enough to beat them); the firmware's autotune on the
    twin, where no gains are known, is no safe answer (exit 1)."""
    problem = build_problem(preset_source("bed", 0), 60.0)
    members = ("fopdt", "sopdt")
    ensemble = Ensemble(tuple(Member(m, (), 1.0, k) for k, m in enumerate(members)), "mean_std", kind="plants")
    ref = [_row("fopdt", "yours", (22.17, 1.36, 241.3), 2.8, 0.155, 0.07, 300.0),
           ProofRow("sopdt", "yours", np.array([22.17, 1.36, 241.3]), 2, 1, (9.0, 9.0), (100.0, 100.0), (1.0, 1.0),
                    (0.07, 0.07), (900.0, 900.0))]
    tripping = [ProofRow(m, "de", np.ones(3), 2, 2, (1.0, 1.0), (100.0, 100.0), (0.1, 0.1), (0.01, 0.01),
                         (200.0, 200.0)) for m in members]
    verdict = judge(tripping + ref, "yours", ["de"], ensemble)
    proof = Proven(verdict, tripping + ref, None, SimpleNamespace(method="yours"), "")  # type: ignore[arg-type]
    printer = PrinterGains(Gains(22.17, 1.36, 241.3), "the last Kp/Ki/Kd the capture printed")
    status, lines = verdict_lines(problem, proof, True, printer)
    assert status == EXIT_ANSWER and lines == [
        f"answer: keep your gains: {CANNOT_MODEL}: on the twin they trip on 1 of the plants the log allows (sopdt); "
        "nothing beats them on all plants: the closest, de, misses on fopdt: trips in 2 of 2 runs (and on 1 more)"]
    status, lines = verdict_lines(problem, proof, True, None)
    assert status == EXIT_UNSAFE and lines[0].endswith("no safe answer was found")
