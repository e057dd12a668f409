"""python -m tools.klipper_host.soak: a line per run and the count (no klippy: the runs are replaced by their
outcomes), and its flags checked in one line."""

from __future__ import annotations

import socket

import pytest

from tools.klipper_host import soak


def test_the_count_is_the_runs_that_held_and_calibrated(monkeypatch, capsys):
    outcomes = iter([(True, "hold within 0.40 C (ok)"), (False, "failed: Timeout on connect"), (True, "ok")])
    monkeypatch.setattr(soak, "run_once", lambda speed, keep: next(outcomes))
    assert soak.main(["--speed", "20", "--runs", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == ["run 1: hold within 0.40 C (ok)", "run 2: failed: Timeout on connect", "run 3: ok",
                     "2 of 3 runs held 180 s within 1 C and calibrated at 20 x"]


@pytest.mark.parametrize("flags", [["--speed", "0"], ["--runs", "0"], ["--speed", "fast"]])
def test_bad_flags_are_one_line(flags, capsys):
    with pytest.raises(SystemExit) as exit_:
        soak.main(flags)
    assert exit_.value.code == 2 and len(capsys.readouterr().err.strip().splitlines()[-1:]) == 1


def test_a_failed_runs_logs_are_kept_and_its_line_says_where(monkeypatch, tmp_path, capsys):
    def session(folder, speed):
        (folder / "klippy.log").write_text(f"run at {speed:g} x\n")
        with socket.socket(socket.AF_UNIX) as api:  # as a session leaves them: klippy's API socket, the pty's link
            api.bind(str(folder / "klippy.sock"))
        (folder / "mcu").symlink_to("/dev/null")
        held = (tmp_path / "kept").exists()  # the second run holds
        return held, "ok" if held else "failed: Timeout on connect"

    monkeypatch.setattr(soak, "_session", session)
    assert soak.main(["--runs", "2", "--speed", "20", "--keep", str(tmp_path / "kept")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:2] == [f"run 1: failed: Timeout on connect (its logs: {tmp_path / 'kept' / 'run-1'})", "run 2: ok"]
    assert sorted(p.name for p in (tmp_path / "kept" / "run-1").iterdir()) == ["klippy.log"]
    assert (tmp_path / "kept" / "run-1" / "klippy.log").read_text() == "run at 20 x\n"
    assert not (tmp_path / "kept" / "run-2").exists()
