"""The twin MCU's peripherals (protocol/klipper_mcu/peripherals.py): TMC drivers over UART and SPI answer as
klippy's tmc_uart.py and tmc2130.py check them (a write reads back, IFCNT counts writes, DRV_STATUS is not a
reset), an accepted command keeps its oid's family, and the buses are enumerated as the chip's firmware names
them."""

from __future__ import annotations

import json
import zlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.klipper_mcu.board import TwinBoard
from protocol.klipper_mcu.dictionary import CHIPS, INVALID_OID, NOT_INPUT_PIN, build_dictionary
from protocol.klipper_mcu.mcu import PRINTER_FAMILIES
from protocol.klipper_mcu.peripherals import crc8_atm, uart_bits, uart_bytes
from tests.klipper_mcu.host import NO_SCENARIO, TestHost

STM32F103 = CHIPS["stm32f103"]
IHOLD_IRUN, DRV_STATUS, IFCNT, GCONF = 0x10, 0x6F, 0x02, 0x00


def host() -> TestHost:
    test_host = TestHost(TwinBoard(NO_SCENARIO, (), wirings=(), fan_pin=None, chip=STM32F103),
                         dictionary=build_dictionary("test", STM32F103, families=PRINTER_FAMILIES))
    test_host.send(0, "allocate_oids count=4")
    return test_host


def uart_datagram(address: int, register: int, value: int | None = None) -> bytes:
    """What klippy's tmc_uart.py sends: sync 0xf5, address, register (bit 7: write), data, CRC8, on the wire."""
    message = bytes([0xF5, address, register]) + (b"" if value is None else value.to_bytes(4, "big"))
    return uart_bits(message + bytes([crc8_atm(message)]))


def uart_read(test_host: TestHost, register: int, address: int = 0) -> int | None:
    test_host.send(0, "tmcuart_send oid=0 read=10", write=uart_datagram(address, register))
    reply = uart_bytes(test_host.named("tmcuart_response")[-1]["read"])
    if reply is None or len(reply) != 8 or crc8_atm(reply[:7]) != reply[7] or reply[:3] != bytes([5, 0xFF, register]):
        return None
    return int.from_bytes(reply[3:7], "big")


@pytest.mark.parametrize("datagram", [
    "05 00 ec 10 00 00 53 9c",  # a CHOPCONF write a TMC2209 took (ST community thread on its UART)
    "55 00 06 e8",  # a read of IOIN and a real TMC2209's reply, captured on a Raspberry Pi's wire
    "05 ff 06 21 00 02 41 9d",
])
def test_the_crc_is_the_one_real_tmc2209s_check(datagram):
    """Datagrams from real TMC2209s, not from the twin: the last byte is CRC-8 (x^8 + x^2 + x + 1, LSB first)."""
    data = bytes.fromhex(datagram)
    assert crc8_atm(data[:-1]) == data[-1]


@given(st.binary(min_size=1, max_size=12))
def test_the_wire_framing_round_trips(data):
    wire = uart_bits(data)
    assert len(wire) == (10 * len(data) + 7) // 8 and uart_bytes(wire)[:len(data)] == data


def test_a_tmc_uart_write_reads_back_and_counts_in_ifcnt():
    test_host = host()
    test_host.send(0, f"config_tmcuart oid=0 rx_pin={STM32F103.pin_number('PC11')} pull_up=1 "
                    f"tx_pin={STM32F103.pin_number('PC10')} bit_time=1000")
    assert uart_read(test_host, IFCNT) == 0
    test_host.send(0, "tmcuart_send oid=0 read=0", write=uart_datagram(0, GCONF | 0x80, 0x1C1))
    assert test_host.named("tmcuart_response")[-1]["read"] == b""
    assert uart_read(test_host, GCONF) == 0x1C1 and uart_read(test_host, IFCNT) == 1
    test_host.send(0, "tmcuart_send oid=0 read=0", write=uart_datagram(0, IHOLD_IRUN | 0x80, 0x0001_1F08))
    assert uart_read(test_host, DRV_STATUS) == 0x1F << 16  # cs_actual = irun: not "Reset?"
    assert uart_read(test_host, GCONF, address=3) == 0  # another driver on the wire, never written
    bad = bytearray(uart_datagram(0, GCONF))
    bad[-1] ^= 0x40  # a CRC bit flipped: the driver stays silent, the line idles high
    test_host.send(0, "tmcuart_send oid=0 read=10", write=bytes(bad))
    assert test_host.named("tmcuart_response")[-1]["read"] == b"\xff" * 10


def test_tmc_spi_answers_the_previous_datagram_down_a_chain():
    test_host = host()
    test_host.send(0, f"config_spi oid=1 pin={STM32F103.pin_number('PB12')} cs_active_high=0")
    write = bytes([GCONF | 0x80, 0, 0, 0x01, 0x04])
    test_host.send(0, "spi_transfer oid=1", data=write)
    test_host.send(0, "spi_transfer oid=1", data=bytes(5))  # klippy's dummy read after a write
    assert test_host.named("spi_transfer_response")[-1]["response"] == bytes([0, 0, 0, 0x01, 0x04])
    test_host.send(0, f"config_spi oid=2 pin={STM32F103.pin_number('PB11')} cs_active_high=0")
    second = bytes(5) + bytes([GCONF | 0x80, 0, 0, 0, 0x07])  # two drivers: write the second's GCONF ...
    test_host.send(0, "spi_send oid=2", data=second)
    read = bytes(5) + bytes([GCONF, 0, 0, 0, 0])  # ... read it, and the next transfer brings it
    test_host.send(0, "spi_send oid=2", data=read)
    test_host.send(0, "spi_transfer oid=2", data=read)
    assert test_host.named("spi_transfer_response")[-1]["response"] == bytes(5) + bytes([0, 0, 0, 0, 0x07])
    test_host.send(0, "spi_transfer oid=1", data=b"\x01\x02\x03")  # not a TMC datagram: zeros
    assert test_host.named("spi_transfer_response")[-1]["response"] == bytes(3)


def test_accepted_commands_keep_their_family_and_check_their_pins():
    test_host = host()
    test_host.send(0, "config_neopixel oid=2 pin=0 data_size=12 bit_max_ticks=100 reset_min_ticks=100")
    test_host.send(0, "neopixel_update oid=2 pos=0", data=b"\x10\x20\x30")
    test_host.send(0, "neopixel_send oid=2")
    assert test_host.named("neopixel_result") == [{"oid": 2, "success": 1}]
    assert not test_host.named("shutdown")
    test_host.send(0, "i2c_write oid=2", data=b"\x00")  # a neopixel's oid is no I2C device
    assert test_host.named("shutdown")[-1]["static_string_id"] == test_host.dictionary.static_string_ids[INVALID_OID]


def test_a_bad_input_pin_shuts_down_as_gpio_in_setup_does():
    test_host = host()
    test_host.send(0, f"config_tmcuart oid=0 rx_pin={7 * 16} pull_up=1 tx_pin=0 bit_time=1000")  # past port G
    assert test_host.named("shutdown")[-1]["static_string_id"] == test_host.dictionary.static_string_ids[
        NOT_INPUT_PIN]


@pytest.mark.parametrize(("chip", "spi", "i2c"), [
    ("stm32f103", {"spi2": 0, "spi1": 1, "spi1a": 2, "spi3": 3}, {"i2c1": 0, "i2c1a": 1, "i2c2": 2}),
    ("atmega2560", {"spi": 0}, {"twi": 0}),
])
def test_the_buses_are_the_firmwares(chip, spi, i2c):
    doc = json.loads(zlib.decompress(build_dictionary("test", CHIPS[chip]).data()))
    assert doc["enumerations"]["spi_bus"] == spi and doc["enumerations"]["i2c_bus"] == i2c
    assert doc["config"]["BUS_PINS_" + next(iter(spi))] == {"stm32f103": "PB14,PB15,PB13",
                                                           "atmega2560": "PB3,PB2,PB1"}[chip]


def test_a_counter_reports_on_the_firmwares_schedule():
    """src/pulse_counter.c with a pin that never changes: the first poll after the clock reports, then the first
    poll strictly after each next sample time (1 poll + 10 polls of sample later: the 12th); count 0."""
    test_host = host()
    test_host.send(0, f"config_counter oid=3 pin={STM32F103.pin_number('PE5')} pull_up=0")
    start = STM32F103.clock_freq
    test_host.send(0, f"query_counter oid=3 clock={start} poll_ticks=1000 sample_ticks=10000")
    test_host.run(start + 30_000)
    assert test_host.named("counter_state") == [
        {"oid": 3, "next_clock": start + 2000, "count": 0, "count_clock": 0},
        {"oid": 3, "next_clock": start + 13_000, "count": 0, "count_clock": 0},
        {"oid": 3, "next_clock": start + 24_000, "count": 0, "count_clock": 0}]
    test_host.send(0, f"query_counter oid=3 clock={start} poll_ticks=0 sample_ticks=10000")  # a poll that spins
    assert test_host.named("shutdown")
