"""Marlin's G-code parser: command letters and codes, parameters, C value semantics, replies."""

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.gcode import STRING_ARG_M_CODES, Command, parse, strtol, unknown_command_text
from protocol.lines import LineReader, with_checksum


def test_a_move_with_every_kind_of_value():
    cmd = parse("G1 X10 Y-2.5 E.5 F+1500")
    assert (cmd.letter, cmd.code, cmd.subcode) == ("G", 1, None)
    assert cmd.params == {"X": "10", "Y": "-2.5", "E": ".5", "F": "+1500"}
    assert cmd.text == "G1 X10 Y-2.5 E.5 F+1500"


def test_line_number_and_checksum_are_not_part_of_the_command():
    cmd = parse("N12 M104 S210 *93")
    assert (cmd.letter, cmd.code, cmd.params, cmd.text) == ("M", 104, {"S": "210"}, "M104 S210")


def test_what_the_line_reader_enqueues_parses_like_the_bare_command():
    (line,) = LineReader().feed((with_checksum("M303 E0 S210 C8 U", 1) + "\n").encode())
    assert parse(line.text) == parse("M303 E0 S210 C8 U")


@pytest.mark.parametrize(
    "text, letter, code",
    [("T1", "T", 1), ("G 1", "G", 1), ("  M105", "M", 105), ("G65537", "G", 1), ("M", "", None), ("X10", "", None)],
)
def test_command_letter_and_code(text, letter, code):
    cmd = parse(text)
    assert (cmd.letter, cmd.code) == (letter, code)


def test_lowercase_is_not_a_command_nor_a_parameter():
    assert parse("g1 X1").letter == ""
    assert parse("M104 s200 T0").params == {"T": "0"}


def test_subcode_after_a_dot():
    assert (parse("G92.1 X0").code, parse("G92.1 X0").subcode) == (92, 1)
    assert parse("G92 X0").subcode is None


def test_values_are_read_with_c_prefix_semantics():
    cmd = parse("M104 S210abc")
    assert cmd.params == {"S": "210"}
    assert cmd.value_int("S") == 210
    assert parse("M104 S12.5x").value_float("S") == 12.5


def test_a_space_between_letter_and_value_is_skipped():
    assert parse("M104 S 210").value_int("S") == 210


def test_letters_run_together_and_flags_without_values():
    cmd = parse("M303 E0S210C8U")
    assert cmd.params == {"E": "0", "S": "210", "C": "8", "U": ""}
    assert cmd.has("U") and not cmd.has("D")
    assert cmd.value_int("U", 7) == 7  # a flag has no value: the default


def test_the_last_occurrence_of_a_letter_wins():
    assert parse("G1 X1 X2").params == {"X": "2"}
    assert parse("G1 X1 X").params == {"X": ""}


def test_string_argument_m_codes_have_no_parameters():
    assert parse("M117 S5 Hello").params == {}


def test_nul_ends_the_string():
    assert parse("M104\0 S200") == Command("M", 104, None, {}, "M104")


def test_value_long_is_a_saturating_32_bit_strtol():
    assert parse("M110 N70000").value_long("N") == 70000
    assert parse("M110 N99999999999").value_long("N") == 2**31 - 1
    assert parse("M110 N").value_long("N", 5) == 5


def test_value_int_is_int16_of_a_saturating_32_bit_strtol():
    assert parse("M104 S70000").value_int("S") == 70000 - 65536
    assert parse("M104 S99999999999").value_int("S") == -1  # 0x7FFFFFFF as int16_t
    assert parse("M104 S1.9").value_int("S") == 1
    assert parse("M104 S-.5").value_int("S") == 0


def test_value_float_is_float32():
    assert parse("M301 P0.1").value_float("P") == struct.unpack("f", struct.pack("f", 0.1))[0]
    assert parse("M301 P1e5").value_float("P") == 1.0  # 'e' is not part of a value
    assert parse("M301 P" + "9" * 60).value_float("P") == float("inf")


def test_value_float_default_without_a_value():
    assert parse("M301 P").value_float("P", 22.2) == 22.2
    assert parse("M301").value_float("P") == 0.0


@pytest.mark.parametrize(
    "text, expected",
    [("M155 S1", True), ("M155 S", True), ("M155 S0", False), ("M155 S-1", False), ("M155 S0.5", False), ("M155", False)],
)
def test_value_bool_is_marlins_boolval(text, expected):
    assert parse(text).value_bool("S") is expected


def test_value_celsius_truncates_like_value_int():
    assert parse("M104 S210.7").value_celsius("S") == 210
    assert parse("M104").value_celsius("S", 180) == 180


@pytest.mark.parametrize(
    "text, reply",
    [
        ("G999", 'echo:Unknown command: "G999"\n'),
        ("N3 G999 X1  *55", 'echo:Unknown command: "G999 X1"\n'),
        ("G999 ", 'echo:Unknown command: "G999 "\n'),  # trailing spaces go only before a '*'
        ("hello", 'echo:Unknown command: "hello"\n'),
        ("", 'echo:Unknown command: ""\n'),
    ],
)
def test_unknown_command_reply_is_marlins(text, reply):
    assert unknown_command_text(parse(text)) == reply


@pytest.mark.parametrize(
    "text, value", [("12", 12), ("  -7x", -7), ("+", 0), ("", 0), ("2147483648", 2**31 - 1), ("-" + "9" * 30, -(2**31))]
)
def test_strtol_is_cs_on_a_32_bit_long(text, value):
    assert strtol(text) == value


# --- properties ------------------------------------------------------------------------------


@given(st.text())
def test_parse_never_raises_and_accessors_never_raise(text):
    cmd = parse(text)
    unknown_command_text(cmd)
    assert cmd.letter in ("", "G", "M", "T")
    for letter in cmd.params:
        assert "A" <= letter <= "Z"
        cmd.value_int(letter)
        cmd.value_float(letter)
        cmd.value_bool(letter)


value_text = st.from_regex(r"[+-]?([0-9]{1,6}(\.[0-9]{0,4})?|\.[0-9]{1,4})", fullmatch=True) | st.just("")
command_code = st.tuples(st.sampled_from("GMT"), st.integers(0, 65535)).filter(
    lambda lc: not (lc[0] == "M" and lc[1] in STRING_ARG_M_CODES)
)


@given(
    command=command_code,
    params=st.dictionaries(st.sampled_from("ABCDEFGHIJKLMNOPQRSTUVWXYZ"), value_text, max_size=8),
    n=st.none() | st.integers(0, 10**6),
)
def test_parameters_round_trip(command, params, n):
    letter, code = command
    words = " ".join(f"{k}{v}" for k, v in params.items())
    text = f"{letter}{code} {words}".rstrip()
    cmd = parse(with_checksum(text, n) if n is not None else text)
    assert (cmd.letter, cmd.code, cmd.subcode, cmd.params, cmd.text) == (letter, code, None, params, text)
    for k, v in params.items():
        assert cmd.value_float(k) == (struct.unpack("f", struct.pack("f", float(v)))[0] if v else 0.0)
        assert cmd.value_int(k) == ((int(float(v)) + 2**15) % 2**16 - 2**15 if v else 0)  # int16_t
