"""Marlin's serial receive path: framing, line numbers, checksums and the exact error replies."""

import functools
import operator
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.lines import (
    MAX_CMD_SIZE,
    STR_ERR_STOPPED,
    Line,
    LineReader,
    checksum,
    with_checksum,
)

# Every line Marlin's receive path can print, as hosts match them.
REPLY_LINE = re.compile(
    r"Error:(Line Number is not Last Line Number\+1|checksum mismatch|No Checksum with line number)"
    r", Last Line: -?\d+"
    r"|Resend: -?\d+"
    r"|ok"
    r"|" + re.escape(STR_ERR_STOPPED)
)


def numbered(line: str, n: int) -> bytes:
    return (with_checksum(line, n) + "\n").encode("latin-1")


def texts(out: list) -> list[str]:
    return [item.text for item in out if isinstance(item, Line)]


def replies(out: list) -> str:
    return "".join(item for item in out if isinstance(item, str))


def split_at(data: bytes, cuts: list[int]) -> list[bytes]:
    bounds = [0, *sorted(c % (len(data) + 1) for c in cuts), len(data)]
    return [data[a:b] for a, b in zip(bounds, bounds[1:])]


# --- framing -------------------------------------------------------------------------------


def test_a_plain_line_is_enqueued_unnumbered():
    assert LineReader().feed(b"M105\n") == [Line("M105", None, None)]


def test_cr_and_lf_both_end_a_line_and_crlf_gives_no_extra_line():
    assert texts(LineReader().feed(b"M105\r\nM104 S0\rM140 S0\n")) == ["M105", "M104 S0", "M140 S0"]


def test_a_line_waits_for_its_end_across_feeds():
    reader = LineReader()
    assert reader.feed(b"M1") == []
    assert texts(reader.feed(b"05\nM1")) == ["M105"]


@pytest.mark.parametrize("data", [b"\n", b"\r\n\r\n", b"; comment\n", b"   \n", b"  ; comment\n", b";\n"])
def test_empty_blank_and_comment_only_lines_give_nothing(data):
    reader = LineReader()
    assert reader.feed(data) == []
    assert reader.last_n == 0


def test_a_comment_is_cut_and_the_spaces_before_it_stay():
    assert texts(LineReader().feed(b"M104 S200 ; set the hotend\n")) == ["M104 S200 "]


def test_backspace_erases_the_previous_character_and_nothing_at_the_start():
    assert texts(LineReader().feed(b"\x08M1055\x08\n")) == ["M105"]


def test_a_backslash_keeps_the_next_character_even_a_semicolon():
    assert texts(LineReader().feed(b"M117 a\\;b\\\\c\n")) == ["M117 a;b\\c"]


def test_a_line_starting_with_an_escaped_semicolon_is_refused_by_the_queue():
    assert LineReader().feed(b"\\;M105\n") == []


def test_a_10kb_line_gives_one_95_char_command_and_the_next_line_is_normal():
    reader = LineReader()
    body = bytes(ord("A") + i % 26 for i in range(10_000))
    assert reader.feed(body) == []
    out = reader.feed(b"\nM105\n")
    assert texts(out) == [body[: MAX_CMD_SIZE - 1].decode(), "M105"]
    assert len(texts(out)[0]) == 95


def test_a_nul_ends_the_line_text():
    assert texts(LineReader().feed(b"M105\x00 junk\n\x00M105\n")) == ["M105"]


def test_bytes_above_0x7f_are_one_latin1_character_each():
    assert texts(LineReader().feed(b"M117 \xe9\xff\n")) == ["M117 \xe9\xff"]


def test_leading_spaces_stay_in_the_text_but_not_in_the_checksum():
    reader = LineReader()
    out = reader.feed(b"  " + numbered("M105", 1))
    assert out == [Line("  " + with_checksum("M105", 1), 1, None)]


# --- line numbers and checksums --------------------------------------------------------------


def test_a_numbered_line_with_a_good_checksum_is_accepted():
    reader = LineReader()
    assert reader.feed(numbered("M105", 1)) == [Line("N1 M105*38", 1, None)]
    assert reader.last_n == 1


def test_wrong_line_number_error_resend_and_ok():
    reader = LineReader(ok_after_resend=True)
    assert reader.feed(numbered("M105", 3)) == [
        "Error:Line Number is not Last Line Number+1, Last Line: 0\nResend: 1\nok\n"
    ]
    assert reader.last_n == 0


def test_checksum_mismatch_error_resend_and_ok():
    reader = LineReader(ok_after_resend=True)
    reader.feed(numbered("M105", 1))
    assert reader.feed(b"N2 M105*0\n") == ["Error:checksum mismatch, Last Line: 1\nResend: 2\nok\n"]
    assert reader.last_n == 1


def test_missing_checksum_error_resend_and_ok():
    assert LineReader(ok_after_resend=True).feed(b"N1 M105\n") == [
        "Error:No Checksum with line number, Last Line: 0\nResend: 1\nok\n"
    ]


@pytest.mark.parametrize(
    "data, error",
    [
        (b"N3 M105*36\n", "Error:Line Number is not Last Line Number+1, Last Line: 0"),
        (b"N1 M105*0\n", "Error:checksum mismatch, Last Line: 0"),
        (b"N1 M105\n", "Error:No Checksum with line number, Last Line: 0"),
    ],
)
def test_by_default_ok_after_resend(data, error):
    """Marlin 2.1's flush_and_request_resend(): Error, Resend, then ok; the option leaves it out."""
    assert LineReader().feed(data) == [f"{error}\nResend: 1\nok\n"]
    assert LineReader(ok_after_resend=False).feed(data) == [f"{error}\nResend: 1\n"]


def test_an_error_discards_the_rest_of_the_rx_buffer_but_not_later_data():
    reader = LineReader()
    out = reader.feed(b"N1 M105*0\nM105\n" + numbered("M105", 1))
    assert texts(out) == []
    assert texts(reader.feed(numbered("M105", 1))) == ["N1 M105*38"]


def test_a_resent_line_already_in_transit_is_ignored_silently():
    reader = LineReader()
    reader.feed(numbered("M105", 1) + numbered("M105", 2))
    assert reader.feed(numbered("M105", 2)) == []  # last_N
    assert reader.feed(numbered("M105", 1)) == []  # last_N - 1
    assert reader.feed(b"N1 garbage*0\n") == []  # not even its checksum is looked at
    assert reader.feed(numbered("M105", 0)).pop().startswith("Error:Line Number")
    assert reader.last_n == 2


def test_m110_with_a_line_number_sets_the_next_number():
    reader = LineReader()
    out = reader.feed(numbered("M110 N100", 0) + numbered("M105", 101))
    assert [(line.text, line.number) for line in out] == [("N0 M110 N100*124", 100), ("N101 M105*39", 101)]
    assert reader.last_n == 101


def test_m110_skips_the_sequence_check_but_not_the_checksum():
    reader = LineReader(ok_after_resend=True)
    assert reader.feed(numbered("M110 N7", 55))[0].number == 7
    assert reader.feed(b"N8 M110 N9*0\n") == ["Error:checksum mismatch, Last Line: 7\nResend: 8\nok\n"]


def test_bare_m110_is_left_to_its_handler_which_sets_last_n():
    reader = LineReader()
    assert reader.feed(b"M110 N100\n") == [Line("M110 N100", None, None)]
    assert reader.last_n == 0
    reader.last_n = 100  # what M110's handler does
    assert texts(reader.feed(numbered("M105", 101))) == ["N101 M105*39"]


def test_a_line_number_must_start_the_line():
    assert LineReader().feed(b"M105 N7\n") == [Line("M105 N7", None, None)]


def test_reset_forgets_the_line_number_the_partial_line_and_the_stop():
    reader = LineReader()
    reader.feed(numbered("M105", 1) + b"M10")
    reader.stopped = True
    reader.reset()
    assert (reader.last_n, reader.stopped) == (0, False)
    assert texts(reader.feed(b"4 S0\n" + numbered("M105", 1))) == ["4 S0", "N1 M105*38"]


@pytest.mark.parametrize(
    "line, expected",
    [("N0 M110 N0", 125), ("N1M110N1", 125), ("N5G28", 54)],  # from OctoPrint and Marlin serial logs
)
def test_checksum_of_lines_seen_on_real_wires(line, expected):
    assert checksum(line) == expected


def test_with_checksum_frames_like_printrun():
    assert with_checksum("M105", 1) == "N1 M105*38"


# --- stopped and emergency commands ----------------------------------------------------------


def test_moves_while_stopped_get_the_stopped_line_before_they_are_enqueued():
    reader = LineReader()
    reader.stopped = True
    out = reader.feed(b"G1 X10\nG28\nM105\nG3 X1 I1\n")
    assert out == [
        STR_ERR_STOPPED + "\n",
        Line("G1 X10", None, None),
        Line("G28", None, None),
        Line("M105", None, None),
        STR_ERR_STOPPED + "\n",
        Line("G3 X1 I1", None, None),
    ]


def test_stopped_text_is_marlins():
    assert STR_ERR_STOPPED == (
        "Printer stopped due to errors. Fix the error and use M999 to restart. "
        "(Temperature is reset. Set it after restarting)"
    )


def test_stopped_check_takes_the_first_g_anywhere_in_the_line():
    reader = LineReader()
    reader.stopped = True
    assert reader.feed(b"M117 Going\n")[0] == STR_ERR_STOPPED + "\n"


@pytest.mark.parametrize(
    "data, emergency",
    [(b"M108\n", "M108"), (b"M112\n", "M112"), (b"  M410\n", "M410"), (b"M1080\n", "M108"), (b"M105\n", None)],
)
def test_emergency_commands_are_flagged_at_receive_time(data, emergency):
    assert LineReader().feed(data)[0].emergency == emergency


def test_a_numbered_emergency_command_is_not_caught_early():
    assert LineReader().feed(numbered("M112", 1))[0].emergency is None


# --- properties ------------------------------------------------------------------------------


# Random bytes mixed with the pieces the receive path reacts to, so every branch is reached.
wire_bytes = st.lists(
    st.one_of(
        st.binary(max_size=8),
        st.sampled_from([b"N", b"N1 ", b"N-2", b"*", b"*0", b"M110 N", b"G1", b"M112", b" ", b";", b"\\", b"\x08", b"\x00"]),
        st.sampled_from([b"\n", b"\r"]),
        st.integers(min_value=1, max_value=3).map(lambda k: numbered("M105", k)),
    ),
    max_size=60,
).map(b"".join)


@given(
    data=wire_bytes,
    cuts=st.lists(st.integers(min_value=0), max_size=8),
    stopped=st.booleans(),
    ok_after_resend=st.booleans(),
)
def test_any_bytes_in_any_chunks_give_well_formed_output(data, cuts, stopped, ok_after_resend):
    reader = LineReader(ok_after_resend=ok_after_resend)
    reader.stopped = stopped
    for chunk in split_at(data, cuts):
        for item in reader.feed(chunk):
            if isinstance(item, Line):
                assert 0 < len(item.text) < MAX_CMD_SIZE
                assert not set(item.text) & set("\n\r\0")
            else:
                assert item.endswith("\n")
                for reply in item[:-1].split("\n"):
                    assert REPLY_LINE.fullmatch(reply), reply


@given(st.text(alphabet=st.characters(max_codepoint=0xFF)))
def test_checksum_is_the_xor_of_the_bytes(text):
    assert checksum(text) == functools.reduce(operator.xor, text.encode("latin-1"), 0)


content = st.text(
    alphabet=st.characters(max_codepoint=0xFF, blacklist_characters="\n\r;\\\x08\x00"), max_size=80
).filter(lambda s: "M110" not in s)


@given(
    lines=st.lists(content, max_size=20),
    first=st.integers(min_value=0, max_value=999),
    cuts=st.lists(st.integers(min_value=0), max_size=10),
)
def test_numbered_checksummed_lines_come_out_exactly_in_order(lines, first, cuts):
    reader = LineReader()
    reader.last_n = first
    framed = [with_checksum(line, first + 1 + k) for k, line in enumerate(lines)]
    stream = b"".join((f + "\n").encode("latin-1") for f in framed)
    out = [item for chunk in split_at(stream, cuts) for item in reader.feed(chunk)]
    assert out == [Line(f, first + 1 + k, None) for k, f in enumerate(framed)]
    assert reader.last_n == first + len(lines)
