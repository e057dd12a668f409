"""The hold check: gains through the public API with ADC noise, per seed, and its verdict."""

import pytest

from tools.cli.hold_check import main


@pytest.mark.slow
def test_quiet_gains_pass_and_a_noisy_derivative_fails(capsys):
    """Kp 10 Ki 0.3 Kd 50 hold hotend_cartridge at 210 C (a robust tune's example); Kd 1000
    turns one LSB of noise into a duty change of several counts per reading."""
    code = main(["--gains", "10,0.3,50", "--gains", "10,0.3,1000", "--seeds", "2", "--duration", "600"])
    lines = capsys.readouterr().out.splitlines()
    assert code == 1
    assert lines[1].startswith("  Kp 10 Ki 0.3 Kd 50: trips 0 of 2") and lines[1].endswith("PASS")
    assert lines[2].startswith("  Kp 10 Ki 0.3 Kd 1000:") and lines[2].endswith("FAIL")
    chatter = float(lines[2].split("chatter ")[1].split(" ")[0])
    assert chatter > 0.03


def test_bad_gains_are_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--gains", "10,0.3"])
    assert exit_.value.code == 2 and "KP,KI,KD" in capsys.readouterr().err
