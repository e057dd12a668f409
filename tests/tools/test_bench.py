"""python -m tools.bench as a tool, never its timings: the command and machine it states, the section --doc
rewrites (and a page without one refused before any work), and the twin-tune benchmark's cases and verdicts."""

from __future__ import annotations

import json
import re

import pytest

from tools import bench, benchmarks

PAGE = "# page\n\nbefore\n\n<!-- bench twin: begin (how) -->\nold block\n<!-- bench twin: end -->\n\nafter\n"


def test_the_doc_section_is_the_run_with_its_command_and_machine(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.delenv(bench.THREADS_ENV, raising=False)
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    assert bench.main(["twin", "--duration", "5", "--lanes", "3", "--doc", str(page)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == f"python -m tools.bench twin --duration 5 --lanes 3 --doc {page}"
    assert re.fullmatch(r"machine: \d+ CPUs \(.+\), load average [\d.]+ over the minute before; "
                        r"\d{4}-\d\d-\d\d \d\d:\d\d UTC, commit \S+.*; the numbers below come from this one run",
                        printed[1]), printed[1]
    assert printed[2] == bench.NOT_MEASURED
    assert printed[3].startswith("single twin (hotend + bed, pid, 5 s heat-and-hold")
    assert page.read_text() == PAGE.replace("old block", "```\n" + "\n".join(printed) + "\n```")


def test_a_run_at_the_default_sizes_is_not_marked(monkeypatch, capsys):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    monkeypatch.delenv(bench.THREADS_ENV, raising=False)
    monkeypatch.setattr(bench, "measure", lambda args: ["measured"])
    assert bench.main(["scaling", "--seed", "2"]) == 0  # a seed is not a size
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == "OPENBLAS_NUM_THREADS=1 python -m tools.bench scaling --seed 2"
    assert printed[1].startswith("machine: ") and printed[2:] == ["measured"]


def test_a_page_without_the_section_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(bench, "measure", lambda args: pytest.fail("measured before the page was checked"))
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    assert bench.main(["protocol", "--doc", str(page)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == (
        f"python -m tools.bench: error: --doc {page}: no '<!-- bench protocol: begin ... -->' / "
        "'<!-- bench protocol: end -->' markers\n")
    assert page.read_text() == PAGE


def test_twin_tune_runs_the_default_tune_then_every_capture_on_each_heater(hardware_logs):
    cases = benchmarks.twin_tune_cases(bench.CAPTURES)
    assert cases[0] == (["--plant", "hotend_cartridge", "--target", "210"], 4.0)
    m303 = sorted(hardware_logs.glob("m303_*.txt"))
    klippy = sorted(hardware_logs.glob("klippy_stats_*.csv"))
    assert m303 and klippy
    expected = sorted([["--from-log", str(path)] for path in m303] + [
        ["--from-log", str(path), "--heater", heater] for path in klippy for heater in ("extruder", "heater_bed")])
    assert sorted(args for args, _ in cases[1:]) == expected
    assert {target for _, target in cases[1:]} == {10.0}
    assert benchmarks.twin_tune_cases(("m303_bed_*.txt",))[1:] == [
        (["--from-log", str(path)], 10.0) for path in sorted(hardware_logs.glob("m303_bed_*.txt"))]


def test_the_verdict_is_twin_tunes_answer_else_its_error(tmp_path):
    answer = tmp_path / "answer.json"
    assert benchmarks._verdict(answer, "progress\ntwin-tune: error: --from-log x: no such file\n") == \
        "twin-tune: error: --from-log x: no such file"
    answer.write_text(json.dumps({"verdict": "new gains", "answer": {"kp": 12.3456, "ki": 0.3, "kd": 70.06},
                                  "why": "trips 4 -> 0"}))
    assert benchmarks._verdict(answer, "") == "new gains Kp 12.35 Ki 0.3 Kd 70.06: trips 4 -> 0"
    answer.write_text(json.dumps({"verdict": "keep your gains", "answer": None, "why": "nothing beats them"}))
    assert benchmarks._verdict(answer, "") == "keep your gains: nothing beats them"


@pytest.mark.slow
def test_twin_tune_bench_runs_the_command(hardware_logs, capsys):
    """The real thing, small: the warm-up, the default tune and two captures twin-tune refuses, each timed."""
    assert bench.main(["twin-tune", "--captures", "m303_hotend_C?_degenerate_*.txt", "--budget", "90",
                       "--proof", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[2] == bench.NOT_MEASURED
    assert re.fullmatch(r"one default job \(python -m tools.cli.sim --no-plot\), the unit below: [\d.]+ s wall, "
                        r"[\d.]+ s CPU \(the median of 3\)", lines[3]), lines[3]
    runs = lines[5:]
    assert len(runs) == 4
    assert re.fullmatch(r"  twin-tune --plant hotend_cartridge --target 210: [\d.]+ x \(target <= 4 x\), [\d.]+ s wall, "
                        r"[\d.]+ s CPU, exit 0: (new gains Kp .+|keep \S+ gains): .+", runs[0]), runs[0]
    assert re.fullmatch(r"  twin-tune --plant hotend_cartridge --target 210 --controller mpc: [\d.]+ x the PID tune's "
                        r"\(target <= 3 x\), [\d.]+ s wall, [\d.]+ s CPU, exit 0: (new gains|keep \S+ gains): .+",
                        runs[1]), runs[1]
    for line in runs[2:]:
        assert re.fullmatch(r"  twin-tune --from-log m303_hotend_C\d_degenerate_\w+\.txt: [\d.]+ x \(target <= 10 x\), "
                            r"[\d.]+ s wall, [\d.]+ s CPU, exit 2: twin-tune: error: .+", line), line


def test_startup_reports_each_commands_help_and_twin_serials_link(monkeypatch, capsys):
    monkeypatch.setattr(benchmarks, "STARTUP_COMMANDS", {"twin-sim": "tools.cli.sim", "tools.seeds": "tools.seeds"})
    assert bench.main(["startup", "--runs", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("python -m tools.bench startup --runs 1")
    assert lines[2] == bench.NOT_MEASURED
    assert lines[3].startswith("start-up CPU time (user + system of the process), median of 1 runs")
    assert [line.split(":")[0] for line in lines[4:]] == ["  twin-sim --help", "  tools.seeds --help",
                                                          "  twin-serial until its link"]
    assert all(re.search(r": \d+\.\d\d s", line) for line in lines[4:])
