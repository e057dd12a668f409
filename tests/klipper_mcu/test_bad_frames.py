"""Frames that are well framed but carry bad values, and frames that are not: the twin MCU answers
them as Klipper's firmware does (src/command.c, basecmd.c, adccmds.c, gpiocmds.c: a shutdown with
its message, a nak, a byte-sized argument truncated, or nothing) and never raises, hangs or grows.
No wall clock: the MCU runs on clocks the test gives it."""

from __future__ import annotations

import tracemalloc

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.klipper_mcu import dictionary as d
from protocol.klipper_mcu.mcu import PRINTER_FAMILIES
from protocol.klipper_mcu.codec import BUFFER_FORMATS, MESSAGE_PAYLOAD_MAX, MESSAGE_SYNC, BlockReader, decode_vlq, frame, parse_messages
from protocol.klipper_mcu.dictionary import CHIPS, build_dictionary, pin_number
from tests.klipper_mcu.host import S, TestHost
from tests.klipper_mcu.test_motion import configure_x, ender3_host

U32_MAX = 2**32 - 1
EXTREMES = (0, 1, 0x7F, 0x80, 0xFF, 0x100, 0xFFFF, 0x10000, 2**31 - 1, 2**31, U32_MAX)
MEMORY_LIMIT_BYTES = 64 << 20


def shutdown_reasons(host: TestHost) -> list[str]:
    by_id = {number: text for text, number in host.dictionary.static_string_ids.items()}
    return [by_id[s["static_string_id"]] for s in host.named("shutdown")]


def configured(strict: bool = False) -> TestHost:
    """klippy's configuration of a hotend, its ADC query and the heater at half power."""
    host = TestHost(strict=strict)
    host.configure()
    host.send(S // 2, "query_analog_in oid=0 clock=16000000 sample_ticks=16000 sample_count=8 rest_ticks=4800000"
                      " min_value=100 max_value=8000 range_check_count=4",
              f"queue_digital_out oid=1 clock={S} on_ticks={S // 20}")
    return host


@pytest.mark.parametrize(("count", "sent"), [(40, 40), (56, 56), (57, None), (60, None), (255, None), (256 + 40, 40)])
def test_identify_count_is_a_byte_and_an_answer_too_long_for_a_block_is_not_sent(count, sent):
    host = TestHost()
    host.send(0, f"identify offset=0 count={count}")
    answers = host.named("identify_response")
    assert host.acks == 1 and not host.named("shutdown")
    assert [len(a["data"]) for a in answers] == ([] if sent is None else [sent])


@pytest.mark.parametrize("offset", [10**6, U32_MAX])
def test_identify_past_the_dictionary_is_empty(offset):
    host = TestHost()
    host.send(0, f"identify offset={offset} count=40")
    assert host.named("identify_response") == [{"offset": offset, "data": b""}]


@pytest.mark.parametrize(("command", "reason"), [
    (f"set_digital_out pin={U32_MAX} value=1", d.NOT_OUTPUT_PIN),  # uint8_t pin 255: past port L
    (f"set_pwm_out pin={4 * 10**9 + 255} cycle_ticks=0 value=1", d.NOT_PWM_PIN),
    (f"config_analog_in oid=0 pin={U32_MAX}", d.NOT_ADC_PIN),
    (f"config_digital_out oid=0 pin={2**32 - 256 + 99} value=0 default_value=0 max_duration=0", d.NOT_OUTPUT_PIN),
])
def test_a_pin_past_the_board_is_the_gpio_shutdown(command, reason):
    host = TestHost()
    host.send(0, "allocate_oids count=2", command)
    assert shutdown_reasons(host) == [reason]


def test_a_pin_number_is_truncated_to_a_byte():
    host = TestHost()
    host.send(0, f"set_digital_out pin={2**32 - 256 + pin_number('PB4')} value=257")  # PB4, value 1 (uint8_t)
    host.run(S)
    assert not host.named("shutdown")
    assert host.board.heaters["hotend"].pin.fractions(1, 10).min() == 1.0


def test_allocate_oids_count_is_a_byte():
    host = TestHost()
    host.send(0, f"allocate_oids count={4 * 10**9}", f"config_analog_in oid=0 pin={pin_number('PK5')}")
    assert shutdown_reasons(host) == [d.CANT_ASSIGN_OID]  # 4e9 & 0xff = 0 oids
    host = TestHost()
    host.send(0, "allocate_oids count=257", f"config_analog_in oid=256 pin={pin_number('PK5')}", "get_config")
    assert not host.named("shutdown")  # one oid, and oid 256 is oid 0


@pytest.mark.parametrize(("oid", "reason"), [(1, d.INVALID_OID), (7, d.INVALID_OID), (U32_MAX, d.INVALID_OID)])
def test_an_oid_of_the_wrong_kind_or_never_allocated(oid, reason):
    host = configured()
    host.send(2 * S, f"query_analog_in oid={oid} clock=0 sample_ticks=1 sample_count=1 rest_ticks=1 min_value=0"
                     " max_value=0 range_check_count=0")
    assert shutdown_reasons(host) == [reason]


@pytest.mark.parametrize(("sample_ticks", "rest_ticks"), [(0, 0), (16000, 16000 * 7)])
def test_an_adc_schedule_that_never_advances_is_rescheduled_in_the_past(sample_ticks, rest_ticks):
    host = configured()
    host.send(2 * S, f"query_analog_in oid=0 clock={3 * S} sample_ticks={sample_ticks} sample_count=8"
                     f" rest_ticks={rest_ticks} min_value=0 max_value=65535 range_check_count=0")
    host.run(4 * S)
    assert shutdown_reasons(host) == [d.RESCHEDULED_IN_PAST]


def test_zero_sample_count_stops_the_reports():
    host = configured()
    host.send(2 * S, "query_analog_in oid=0 clock=0 sample_ticks=0 sample_count=256 rest_ticks=0 min_value=0"
                     " max_value=0 range_check_count=0")  # 256 is a count of 0 (uint8_t)
    before = len(host.named("analog_in_state"))
    host.run(5 * S)  # (before the heater's max_duration)
    assert len(host.named("analog_in_state")) == before and not host.named("shutdown")


def test_a_sum_wraps_at_16_bits_and_range_values_are_half_words():
    host = TestHost()
    host.configure()  # the heater stays off: the hotend at the 25 C ambient
    host.send(2 * S, f"query_analog_in oid=0 clock={3 * S} sample_ticks=1600 sample_count=255 rest_ticks={S}"
                     f" min_value={2**16 + 100} max_value={U32_MAX} range_check_count=1")
    host.run(4 * S)
    assert host.named("analog_in_state")[-1]["value"] == (255 * 978) & 0xFFFF  # 25 C ambient: 978 per sample
    assert not host.named("shutdown")  # min 100, max 65535: in range


def test_a_two_byte_message_id_and_an_unknown_one():
    host = TestHost()
    get_clock = host.dictionary.commands["get_clock"].msg_id
    host.raw(0, frame(0, bytes((0x80, get_clock))))  # (0x80 & 0x7f) << 7 | id: the same command
    assert host.named("clock") == [{"clock": 0}]
    host.raw(0, frame(1, bytes((0x81, get_clock))))
    assert shutdown_reasons(host) == [d.INVALID_COMMAND]
    assert host.acks == 2  # the block is still acknowledged


def test_a_response_id_is_an_invalid_command():
    host = TestHost()
    host.raw(0, frame(0, bytes((host.dictionary.responses["clock"].msg_id,))))
    assert shutdown_reasons(host) == [d.INVALID_COMMAND]


def test_an_integer_may_run_into_the_trailer_but_no_parameter_may_start_past_it():
    host = TestHost()
    commands = host.dictionary.commands
    payload = commands["get_clock"].encode() + bytes((commands["finalize_config"].msg_id,))  # crc: the CRC bytes
    block = frame(0, payload)
    host.raw(S, block)
    host.sequence = 1
    host.send(S, "get_config")
    trailer_crc = decode_vlq(block, 2 + len(payload))[0]
    assert host.named("config") == [{"is_config": 1, "crc": trailer_crc, "is_shutdown": 0, "move_count": 1024}]
    host.raw(S, frame(2, commands["get_clock"].encode() + bytes((commands["queue_digital_out"].msg_id, 0x81))))
    assert len(host.named("clock")) == 2  # the command before the bad one ran
    assert shutdown_reasons(host) == [d.PARSER_ERROR]  # oid ran past the end: clock starts beyond it


def test_a_shutdown_ends_the_block():
    host = TestHost()
    host.send(0, "emergency_stop", "get_clock")
    assert shutdown_reasons(host) == [d.COMMAND_REQUEST] and not host.named("clock")


def test_an_overlong_integer_keeps_its_low_32_bits():
    host = TestHost()
    payload = bytes((host.dictionary.commands["identify"].msg_id,)) + b"\xff" * 8 + b"\x00" + b"\x05"
    host.raw(0, frame(0, payload))  # offset 0xff..80 (32 bits kept), count 5
    assert host.named("identify_response") == [{"offset": 0xFFFFFF80, "data": b""}]


def test_garbage_gets_one_nak_and_the_next_good_block_is_served():
    host = TestHost()
    bad = bytearray(frame(0, host.dictionary.commands["get_clock"].encode()))
    bad[-2] ^= 1  # CRC
    host.raw(0, b"\x01\x02\x03" + bytes(bad) + bytes((70, 0x10, 0, 0, MESSAGE_SYNC)))
    assert host.acks == 1 and not host.responses
    host.send(0, "get_clock")
    assert host.named("clock") == [{"clock": 0}]


def _blocks(commands: dict) -> st.SearchStrategy[bytes]:
    """A frame of one or more commands with values at their extremes, a random payload (overlong
    integers, unknown ids), a broken one (CRC, length, sequence, sync) or bytes between frames."""
    value = st.sampled_from(EXTREMES) | st.integers(0, U32_MAX)
    data = st.binary(max_size=MESSAGE_PAYLOAD_MAX)  # a buffer parameter (a display's or an SPI device's bytes)
    command = st.sampled_from(sorted(commands)).flatmap(
        lambda name: st.fixed_dictionaries({p: data if f in BUFFER_FORMATS else value
                                            for p, f in commands[name].params}).map(
            lambda values, fmt=commands[name]: fmt.encode(**values)))
    good = st.lists(command, min_size=1, max_size=4).map(b"".join).filter(lambda p: len(p) <= MESSAGE_PAYLOAD_MAX)
    payload = good | st.binary(max_size=MESSAGE_PAYLOAD_MAX)
    return st.tuples(payload, st.sampled_from(("good", "good", "good", "crc", "length", "sequence", "garbage")))


def _damage(block: bytes, how: str, sequence: int) -> bytes:
    if how == "crc":
        return block[:-3] + bytes(((block[-3] + 1) & 0xFF,)) + block[-2:]
    if how == "length":
        return bytes(((block[0] + 7) & 0xFF,)) + block[1:]
    if how == "sequence":
        return frame(sequence + 3, block[2:-3])
    return bytes((0x33, MESSAGE_SYNC, 0x10)) + block


@pytest.mark.slow  # thousands of frames under the ci profile: 6-15 s each on a quiet 2-core machine
@pytest.mark.parametrize("strict", [False, True])
@given(frames=st.lists(st.tuples(_blocks(TestHost().dictionary.commands), st.integers(0, S // 10)), max_size=12),
       configure=st.booleans())
def test_no_frame_crashes_hangs_or_grows_the_mcu(strict, frames, configure):
    fuzz(configured(strict) if configure else TestHost(strict=strict), frames)


PRINTER_COMMANDS = build_dictionary("test", CHIPS["atmega1284p"], families=PRINTER_FAMILIES).commands


@pytest.mark.slow  # thousands of frames under the ci profile: 6-15 s each on a quiet 2-core machine
@pytest.mark.parametrize("strict", [False, True])
@given(frames=st.lists(st.tuples(_blocks(PRINTER_COMMANDS), st.integers(0, S // 10)), max_size=12),
       configure=st.booleans())
def test_no_frame_crashes_hangs_or_grows_a_printer_cfg_board(tmp_path_factory, strict, frames, configure):
    """The same on a printer.cfg's board, steppers, endstops, trsyncs, displays and SPI included."""
    host, config = ender3_host(tmp_path_factory.mktemp("cfg"), strict=strict)
    if configure:
        configure_x(host, config.chip)
    fuzz(host, frames)


def fuzz(host: TestHost, frames) -> None:
    responses = {fmt.msg_id: fmt for fmt in host.dictionary.responses.values()}
    reader = BlockReader()
    clock, sequence = 2 * S, host.sequence
    tracemalloc.start()
    try:
        for (payload, how), step in frames:
            clock += step
            block = frame(sequence, payload)
            host.mcu.receive(block if how == "good" else _damage(block, how, sequence), clock)
            for answer in reader.feed(host.mcu.take_output()):
                assert answer is not None, "the MCU sent a corrupt block"
                parse_messages(answer.payload, responses)  # every answer is a response it declares
                sequence = answer.sequence
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    host.mcu.run_until(clock + 7 * S)  # past a max_duration of 5 s and its grace: no timer spins
    assert peak < MEMORY_LIMIT_BYTES
