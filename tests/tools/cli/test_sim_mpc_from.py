"""twin-sim --mpc-from: the model of an M306 line (argument or file) runs the hotend; bad input
gets one line naming the flag and exit status 2."""

from __future__ import annotations

from tools.cli.sim import main as twin_sim

RUN = ["--no-bed", "--duration", "5", "--no-plot"]


def test_a_line_or_a_file_sets_the_model_and_the_rest_stays_configuration_h(tmp_path, capsys):
    assert twin_sim(["--firmware", "mpc", "--mpc-from", "M306 C12.5 R0.15", *RUN, "--out", str(tmp_path)]) == 0
    assert "mpc: M306 E0 P40.00 C12.50 R0.1500 A0.0680 F0.0970 H0.0056" in capsys.readouterr().out.splitlines()
    saved = tmp_path / "fit.txt"
    saved.write_text("twin-fit: some.log\n  Marlin:  M306 P30.00 C8.33 R0.1345 A0.0381 F0.0381\n")
    assert twin_sim(["--firmware", "mpc", "--mpc-from", str(saved), *RUN, "--out", str(tmp_path)]) == 0
    assert "mpc: M306 E0 P30.00 C8.33 R0.1345 A0.0381 F0.0381 H0.0056" in capsys.readouterr().out.splitlines()


def test_without_an_m306_line_or_without_mpc_it_is_one_line_and_status_2(tmp_path, capsys):
    empty = tmp_path / "empty.txt"
    empty.write_text("no settings here\n")
    for argv, message in (
        (["--firmware", "pid", "--mpc-from", "M306 C12"], "--mpc-from sets MPC's model: it needs --firmware mpc"),
        (["--firmware", "mpc", "--mpc-from", str(empty)], f"--mpc-from '{empty}': no M306 line with constants"),
        (["--firmware", "mpc", "--mpc-from", "M306 T"], "--mpc-from 'M306 T': no M306 line with constants"),
    ):
        assert twin_sim([*argv, *RUN, "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("twin-sim: error: ") and message in err and err.count("\n") == 1
