"""The golden transcript: the scripted session must reproduce tests/golden/marlin_session.txt line by line."""

from tools.validation.golden import GOLDEN_PATH, record_session


def test_session_matches_the_golden_transcript_line_by_line():
    expected = GOLDEN_PATH.read_text().splitlines()
    got = record_session()
    for number, (want, have) in enumerate(zip(expected, got), start=1):
        assert have == want, f"line {number} differs (regenerate only on purpose: python -m tools.validation.golden --write)"
    assert len(got) == len(expected)


def test_the_golden_session_covers_what_the_issue_asks_for():
    lines = GOLDEN_PATH.read_text().splitlines()
    assert lines[0] == "< start"
    for needle in ("> M115", "< FIRMWARE_NAME:Marlin", "> M105", "> N1 M104 S200*", "> N2 M109 S200*", " W:",
                   "> N3 M303 E0 S210 C8*", "< PID Autotune start", "< #define DEFAULT_Kd ",
                   "< Error:checksum mismatch, Last Line: 3", "< Resend: 4", "> M112", "< echo:M112 Shutdown",
                   "< Error:Printer halted. kill() called!"):
        assert any(needle in line for line in lines), needle
    assert lines[-1] == "> M105"  # a killed board answers nothing
    resend = lines.index("< Resend: 4")
    assert lines[resend + 1] == "< ok"  # Marlin 2.1's flush_and_request_resend() ends with ok
