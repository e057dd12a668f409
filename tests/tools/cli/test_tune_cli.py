"""twin-tune end to end: the acceptance run on hotend_cartridge, a fitted log, one-line errors,
a tune on a dask LocalCluster equal to in-process, and docs/tuning.md's table still current."""

from __future__ import annotations

import re

import numpy as np
import pytest
from distributed import Client, LocalCluster

from tools.cli.tune import main
from tools.docs import rules_table as table
from tools.tuning.defaults import rule_names
from tools.tuning.evaluate import preset_problem
from tools.tuning.tuner import tune

ROW = re.compile(r"^ [ *](\S+(?: C8| #\d+)?)\s+Kp \S+ Ki \S+ Kd \S+\s+cost\s+(\S+)", re.M)
TO_BEAT = re.compile(r"^to beat: (M303 C8)\s+Kp \S+ Ki \S+ Kd \S+\s+cost (\S+)$", re.M)
BEST = re.compile(r"^best of the search: (\S+(?: #\d+)?)\s+Kp (\S+) Ki (\S+) Kd (\S+)\s+cost (\S+)$", re.M)


@pytest.mark.slow


def test_every_rule_on_hotend_cartridge_beats_or_loses_to_m303_and_the_best_beats_it(capsys, tmp_path):
    """The acceptance run: the best rule beats the twin's own M303 C8 on the heater objective."""
    plot = tmp_path / "tune.png"
    assert main(["--plant", "hotend_cartridge", "--target", "210", "--method", "auto", "--budget", "90",
                 "--spread", "0", "--noise", "0", "--proof", "0", "--plot", str(plot)]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "eval" not in captured.err  # no progress bar when stderr is not a terminal
    best, reference = BEST.search(out), TO_BEAT.search(out)
    assert best is not None and reference is not None, out  # no printer gains: the twin's own M303 is to beat
    assert best.group(1) in rule_names() + ["de"] or best.group(1).startswith("de #")
    assert float(best.group(5)) < float(reference.group(2))
    costs = {name: float(cost) for name, cost in ROW.findall(out)}
    assert min(costs[rule] for rule in rule_names()) < costs["M303 C8"]  # the acceptance: a rule beats M303
    for paste in ("M301 E0 P", "  M500", "#define DEFAULT_Kp"):
        assert paste in out
    assert "not proven (--proof 0)" in out and "[extruder]" not in out  # Klipper's block from the Klipper loop only
    for rule in rule_names():
        assert re.search(rf"^ [ *]{re.escape(rule)}\s+Kp", out, re.M), rule
    assert plot.stat().st_size > 10_000


@pytest.mark.slow  # 13.7 s of CPU: fits, profiles and tunes a capture
def test_a_fitted_log_is_tuned(capsys, tmp_path, hardware_logs):
    log = hardware_logs / "klipper_heattest_onionheater_heattest_200.csv"
    method = rule_names()[0]
    assert main(["--from-log", str(log), "--method", method, "--spread", "0", "--noise", "0", "--proof", "0",
                 "--plot", "none"]) == 0
    out = capsys.readouterr().out
    assert "klipper_heattest_onionheater_heattest_200.csv (two_node" in out
    assert re.search(rf"^ [ *]{method}\s+Kp \S+ Ki \S+ Kd \S+\s+cost", out, re.M)  # the rule ran, scored
    assert "plant: two_node fitted to klipper_heattest_onionheater_heattest_200.csv as twin-fit fits it:" in out


@pytest.mark.parametrize("argv, flag", [
    (["--plant", "nope"], "--plant"),
    (["--plant", "hotend_cartridge", "--target", "900"], "--target"),
    (["--plant", "hotend_cartridge", "--objective", "fastest"], "--objective"),
    (["--plant", "hotend_cartridge", "--loop", "repetier"], "argument --loop"),
    (["--plant", "hotend_cartridge", "--target", "nan"], "argument --target"),
    (["--plant", "hotend_cartridge", "--target", "-50"], "--target"),
    (["--plant", "hotend_cartridge", "--plot", "/nonexistent/t.png"], "--plot"),
    (["--plant", "hotend_cartridge", "--controller", "bangbang"], "--controller bangbang: 'bangbang' has no parameters"),
    (["--plant", "hotend_cartridge", "--controller", "nomodule_xyz:SPACE"], "--controller"),
    (["--plant", "hotend_cartridge", "--controller", "fuzzy_pi", "--loop", "klipper"], "--loop klipper"),
    (["--plant", "hotend_cartridge", "--controller", "fuzzy_pi", "--method", "amigo"], "--method amigo"),
    (["--plant", "hotend_cartridge", "--noise", "-1"], "--noise"),
    (["--plant", "hotend_cartridge", "--spread", "1.5"], "--spread"),
    (["--plant", "hotend_cartridge", "--proof", "-2"], "--proof"),
    (["--plant", "hotend_cartridge", "--statistic", "median"], "argument --statistic"),
    (["--plant", "hotend_cartridge", "--budget", "0"], "--budget"),
    (["--plant", "hotend_cartridge", "--method", "guess"], "--method"),
    (["--plant", "hotend_cartridge", "--method", "alo", "--budget", "3"], "--method alo --budget 3"),
    (["--plant", "hotend_cartridge", "--model", "fifth_order"], "--model"),
])
def test_bad_input_is_one_line_naming_the_flag(capsys, argv, flag):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"twin-tune: error: {flag}"), err


def test_a_missing_log_is_one_line(capsys, tmp_path):
    assert main(["--from-log", str(tmp_path / "none.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "none.csv" in err


@pytest.mark.slow


def test_a_tune_on_a_local_dask_cluster_equals_in_process():
    """Same seed, DE's three generations of 45 on two workers: the same gains and costs."""
    problem = preset_problem("hotend_cartridge", 210)
    local = tune(problem, method="de", budget=135, seed=3)
    with LocalCluster(n_workers=2, processes=False, dashboard_address=None) as cluster, Client(cluster) as client:
        remote = tune(problem, method="de", budget=135, seed=3, client=client)
    assert [c.method for c in remote.candidates] == [c.method for c in local.candidates]
    for a, b in zip(local.candidates + local.references, remote.candidates + remote.references, strict=True):
        assert (a.gains, a.cost) == (b.gains, b.cost)  # identical chunks, identical arithmetic


@pytest.mark.slow


def test_the_rules_table_in_the_docs_is_current():
    """docs/tuning.md's table against a fresh run, with table.same_table's tolerances."""
    problems = table.same_table(table.table_of(table.DOC.read_text()), table.generate())
    assert not problems, "\n".join(problems[:20]) + "\nregenerate with: python -m tools.docs.rules_table"


def test_same_table_tolerates_small_moves_but_not_verdicts():
    a = "| hotend | 210 | simc | 10.0 | 0.5 | 100 | beats |"
    assert table.same_table(a, a.replace("10.0", "10.1")) == []
    assert table.same_table(a, a.replace("10.0", "11")) != []
    assert table.same_table(a, a.replace("beats", "loses")) != []
    assert np.isclose(10.0, 10.1, rtol=table.REL_TOL)


@pytest.mark.slow  # 4.3 s of CPU: a tune and its proof
def test_the_answer_for_a_program_json_progress_lines_and_your_gains(capsys, tmp_path):
    """--current-gains sets the gains to beat; --json writes the verdict, the gains and the proof rows a
    program reads; --progress lines reports each step on stderr, 'progress: <step> <done>/<total>'."""
    import json

    answer = tmp_path / "answer.json"
    status = main(["--plant", "hotend", "--target", "200", "--budget", "90", "--proof", "2", "--plot", "none",
                   "--current-gains", "M301 P22.2 I1.08 D114", "--json", str(answer), "--progress", "lines",
                   "--cross-check", "10"])
    captured = capsys.readouterr()
    document = json.loads(answer.read_text())
    assert status in (0, 1) and document["verdict"] in ("new gains", "keep your gains")
    assert document["current"]["kp"] == 22.2 and document["current"]["source"] == "--current-gains"
    assert "your gains: Kp 22.2 Ki 1.08 Kd 114 (--current-gains)" in captured.out
    assert re.search(r"^answer: (new gains \(.+\)|keep your gains): ", captured.out, re.M)
    if document["verdict"] == "new gains":
        assert document["commands"][0].startswith("M301 E0 P") and document["commands"][1] == "M500"
    else:
        assert document["answer"] is None and document["commands"] == []
    yours = [r for r in document["proof"] if r["candidate"] == "yours"]
    assert len(yours) == 5 and {r["runs"] for r in yours} == {2}  # a row per member, 2 seeds each
    steps = re.findall(r"^progress: (.+) (\d+)/(\d+)$", captured.err, re.M)
    assert {"proving", "searching (de)"} <= {s for s, _, _ in steps}
    assert ("proving", "5", "5") in steps and "bit for bit" in captured.out  # the cross-check ran


@pytest.mark.slow  # 3.9 s of CPU: a tune
def test_proof_zero_never_says_proven(capsys):
    assert main(["--plant", "hotend", "--budget", "90", "--proof", "0", "--plot", "none"]) == 0
    out = capsys.readouterr().out
    assert "not proven (--proof 0)" in out and "UNPROVEN" in out
    assert "proven on" not in out and "answer:" not in out
