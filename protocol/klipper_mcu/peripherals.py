"""The twin MCU's peripherals beyond heaters and motion: what a printer.cfg's displays, buttons, SPI and I2C
devices, TMC stepper drivers and neopixels need of the MCU for klippy to run them.

Most are accepted as the firmware accepts them and do nothing (nothing is drawn, no button is pressed, an LED
shows nothing): ``ACCEPTED`` says, per command, whether it configures an oid (and which of its pins are outputs
or inputs, checked as gpio_out_setup and gpio_in_setup check them) or uses one of its family. Those that answer:

- ``spi_transfer``: an SPI device answers as a TMC2130/2240/5160 on it would (``TmcSpi``), else zeros;
- ``tmcuart_send``: a TMC2208/2209/2225 on the wire answers reads, counts writes in IFCNT (``TmcUart``), in
  klippy's bit-banged framing (src/tmcuart.c: 10 bits a byte, start 0, LSB first, stop 1);
- ``i2c_read``: zeros of the length asked; ``neopixel_send``: success;
- ``query_counter`` (a fan's tachometer, a pulse counter): counter_state reports on src/pulse_counter.c's
  schedule, counting nothing (no simulated pulses: a tachometer reads 0 RPM).
The formats are those of klippy 0.12 (src/i2ccmds.c before i2c_transfer replaced i2c_write and i2c_read).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from protocol.klipper_mcu.dictionary import INVALID_OID, RESCHEDULED_IN_PAST, Chip, Shutdown
from protocol.klipper_mcu.motion import MIN_PERIOD_S

if TYPE_CHECKING:
    from collections.abc import Callable

COMMANDS = (
    "config_st7920 oid=%c cs_pin=%u sclk_pin=%u sid_pin=%u sync_delay_ticks=%u cmd_delay_ticks=%u",
    "st7920_send_cmds oid=%c cmds=%*s",
    "st7920_send_data oid=%c data=%*s",
    "config_hd44780 oid=%c rs_pin=%u e_pin=%u d4_pin=%u d5_pin=%u d6_pin=%u d7_pin=%u delay_ticks=%u",
    "hd44780_send_cmds oid=%c cmds=%*s",
    "hd44780_send_data oid=%c data=%*s",
    "config_buttons oid=%c button_count=%c",
    "buttons_add oid=%c pos=%c pin=%u pull_up=%c",
    "buttons_query oid=%c clock=%u rest_ticks=%u retransmit_count=%c invert=%c",
    "buttons_ack oid=%c count=%c",
    "config_spi oid=%c pin=%u cs_active_high=%c",
    "config_spi_without_cs oid=%c",
    "spi_set_bus oid=%c spi_bus=%u mode=%u rate=%u",
    "spi_set_software_bus oid=%c miso_pin=%u mosi_pin=%u sclk_pin=%u mode=%u rate=%u",
    "spi_transfer oid=%c data=%*s",
    "spi_send oid=%c data=%*s",
    "config_i2c oid=%c",
    "i2c_set_bus oid=%c i2c_bus=%u rate=%u address=%u",
    "i2c_set_software_bus oid=%c scl_pin=%u sda_pin=%u rate=%u address=%u",
    "i2c_write oid=%c data=%*s",
    "i2c_read oid=%c reg=%*s read_len=%u",
    "i2c_modify_bits oid=%c reg=%*s clear_set_bits=%*s",
    "config_tmcuart oid=%c rx_pin=%u pull_up=%c tx_pin=%u bit_time=%u",
    "tmcuart_send oid=%c write=%*s read=%c",
    "config_neopixel oid=%c pin=%u data_size=%hu bit_max_ticks=%u reset_min_ticks=%u",
    "neopixel_update oid=%c pos=%hu data=%*s",
    "neopixel_send oid=%c",
    "config_counter oid=%c pin=%u pull_up=%c",
    "query_counter oid=%c clock=%u poll_ticks=%u sample_ticks=%u",
)
RESPONSES = (
    "buttons_state oid=%c ack_count=%c state=%*s",
    "spi_transfer_response oid=%c response=%*s",
    "i2c_read_response oid=%c response=%*s",
    "tmcuart_response oid=%c read=%*s",
    "neopixel_result oid=%c success=%c",
    "counter_state oid=%c next_clock=%u count=%u count_clock=%u",
)
FAMILY = (COMMANDS, RESPONSES)


@dataclass(frozen=True)
class Accepted:
    """What the twin does with an accepted command: ``config`` allocates its oid for ``family`` (after checking
    its ``outputs`` and ``inputs`` pins); otherwise the oid must be one of ``family``'s."""

    family: str
    config: bool = False
    outputs: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()


ACCEPTED = {
    "config_st7920": Accepted("st7920", True, ("cs_pin", "sclk_pin", "sid_pin")),
    "st7920_send_cmds": Accepted("st7920"),
    "st7920_send_data": Accepted("st7920"),
    "config_hd44780": Accepted("hd44780", True, ("rs_pin", "e_pin", "d4_pin", "d5_pin", "d6_pin", "d7_pin")),
    "hd44780_send_cmds": Accepted("hd44780"),
    "hd44780_send_data": Accepted("hd44780"),
    "config_buttons": Accepted("buttons", True),
    "buttons_add": Accepted("buttons", inputs=("pin",)),
    "buttons_query": Accepted("buttons"),
    "buttons_ack": Accepted("buttons"),
    "config_spi": Accepted("spi", True, ("pin",)),
    "config_spi_without_cs": Accepted("spi", True),
    "spi_set_bus": Accepted("spi"),
    "spi_set_software_bus": Accepted("spi", outputs=("mosi_pin", "sclk_pin"), inputs=("miso_pin",)),
    "config_i2c": Accepted("i2c", True),
    "i2c_set_bus": Accepted("i2c"),
    "i2c_set_software_bus": Accepted("i2c", outputs=("scl_pin", "sda_pin")),
    "i2c_write": Accepted("i2c"),
    "i2c_modify_bits": Accepted("i2c"),
    "config_tmcuart": Accepted("tmcuart", True, ("tx_pin",), ("rx_pin",)),
    "config_neopixel": Accepted("neopixel", True, ("pin",)),
    "neopixel_update": Accepted("neopixel"),
    "config_counter": Accepted("counter", True, inputs=("pin",)),
}


@dataclass(eq=False)
class Device:
    """An oid of one of the peripheral families; ``tmc``: the TMC drivers it talks to (SPI: by place in the
    chain; UART: by address)."""

    oid: int
    family: str
    tmc: dict[int, TmcRegisters] = field(default_factory=dict)
    timer: int = 0  # the version of its pending timer (a counter's reports)


@dataclass
class TmcRegisters:
    """A TMC driver's registers as a host sees them: what was written reads back; IFCNT (UART register 2)
    counts the writes it took, modulo 256; DRV_STATUS reports no error and the run current (cs_actual, which
    klippy reads as 0 after a reset) from IHOLD_IRUN; any other register never written reads 0."""

    values: dict[int, int] = field(default_factory=dict)
    writes: int = 0
    spi_reply: int = 0  # SPI: the next datagram's data (a read's register, or the value just written)

    def write(self, register: int, value: int) -> None:
        self.values[register] = value & 0xFFFFFFFF
        self.writes = (self.writes + 1) & 0xFF

    def read(self, register: int) -> int:
        if register == IFCNT:
            return self.writes
        if register == DRV_STATUS:
            return ((self.values.get(IHOLD_IRUN, 0) >> 8) & 0x1F) << 16  # irun (bits 8-12) as cs_actual (16-20)
        return self.values.get(register, 0)


IFCNT = 0x02  # TMC2208/2209: the UART write counter klippy checks after each write
IHOLD_IRUN, DRV_STATUS = 0x10, 0x6F  # the same addresses on the TMC2130, 2208, 2209, 2240 and 5160
SPI_DATAGRAM = 5  # TMC2130/5160: 40-bit datagrams, address (bit 7: write) then 32 bits of data
UART_SYNC, UART_REPLY_ADDRESS = 0x05, 0xFF  # a TMC22xx reply's sync nibble and its master address


def tmc_spi_transfer(device: Device, data: bytes) -> bytes:
    """An SPI transfer to TMC drivers in a daisy chain (one per 5 bytes): each answers a status byte and the
    data its previous datagram asked for (a read: the register; a write: the value written)."""
    if not data or len(data) % SPI_DATAGRAM:
        return bytes(len(data))
    reply = bytearray()
    for place in range(len(data) // SPI_DATAGRAM):
        datagram = data[place * SPI_DATAGRAM:(place + 1) * SPI_DATAGRAM]
        tmc = device.tmc.setdefault(place, TmcRegisters())
        reply += bytes([0]) + tmc.spi_reply.to_bytes(4, "big")
        register, value = datagram[0] & 0x7F, int.from_bytes(datagram[1:], "big")
        if datagram[0] & 0x80:
            tmc.write(register, value)
            tmc.spi_reply = value
        else:
            tmc.spi_reply = tmc.read(register)
    return bytes(reply)


def crc8_atm(data: bytes) -> int:
    """The TMC22xx UART CRC (CRC-8, polynomial 0x07, bits taken LSB first)."""
    crc = 0
    for byte in data:
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07 if (crc >> 7) ^ (byte & 1) else crc << 1) & 0xFF
            byte >>= 1
    return crc


def uart_bits(data: bytes) -> bytes:
    """Bytes as the wire carries them: each a start bit 0, 8 data bits LSB first and a stop bit 1, packed LSB
    first into bytes (src/tmcuart.c's buffer)."""
    bits = 0
    for place, byte in enumerate(data):
        bits |= ((byte << 1) | 0x200) << (10 * place)
    return bits.to_bytes((10 * len(data) + 7) // 8, "little")


def uart_bytes(wire: bytes) -> bytes | None:
    """``uart_bits`` undone; None where a start or stop bit is wrong."""
    bits, out = int.from_bytes(wire, "little"), bytearray()
    for place in range(len(wire) * 8 // 10):
        frame = (bits >> (10 * place)) & 0x3FF
        if frame & 1 or not frame & 0x200:
            return None
        out.append((frame >> 1) & 0xFF)
    return bytes(out)


def tmc_uart_exchange(device: Device, wire: bytes) -> bytes:
    """One tmcuart_send: a write datagram (8 bytes) is taken, a read (4 bytes) answered in 8 bytes; a datagram
    with a bad CRC or framing gets no answer, as a driver ignores it."""
    message = uart_bytes(wire)
    if message is None or len(message) not in (4, 8) or crc8_atm(message[:-1]) != message[-1]:
        return b""
    tmc = device.tmc.setdefault(message[1], TmcRegisters())
    register = message[2] & 0x7F
    if len(message) == 8:
        if message[2] & 0x80:
            tmc.write(register, int.from_bytes(message[3:7], "big"))
        return b""
    reply = bytes([UART_SYNC, UART_REPLY_ADDRESS, register]) + tmc.read(register).to_bytes(4, "big")
    return uart_bits(reply + bytes([crc8_atm(reply)]))


class PeripheralCommands:
    """KlipperMcu's handlers for FAMILY's commands (a mixin: the oids and output are the MCU's)."""

    if TYPE_CHECKING:  # what the mixin uses of KlipperMcu
        chip: Chip
        now: int
        def world_clock(self, clock32: int) -> int: ...
        def mcu_clock(self, clock: int) -> int: ...
        def _add_timer(self, clock: int, action: Callable, owner, *args) -> None: ...
        def _alloc(self, oid: int, obj: object) -> None: ...
        def _lookup(self, oid: int, kind: type): ...
        def _send(self, name: str, **values) -> None: ...
        def _output_pin(self, number: int, reason: str = ...) -> str: ...
        def _input_pin(self, number: int) -> str: ...

    def _accepted(self, name: str) -> Callable[[dict], None]:
        """The handler of an ACCEPTED command (KeyError: the dictionary names a command nobody handles)."""
        accepted = ACCEPTED[name]
        return lambda args: self._accept(accepted, args)

    def _accept(self, accepted: Accepted, args: dict) -> None:
        if not accepted.config:
            self._device(args["oid"], accepted.family)
        for pin in accepted.outputs:
            self._output_pin(args[pin])
        for pin in accepted.inputs:
            self._input_pin(args[pin])
        if accepted.config:
            self._alloc(args["oid"], Device(args["oid"] & 0xFF, accepted.family))

    def _device(self, oid: int, family: str) -> Device:
        """The oid's device, if it is of ``family`` (else "Invalid oid type", as oid_lookup says)."""
        device = self._lookup(oid, Device)
        if device.family != family:
            raise Shutdown(INVALID_OID)
        return device

    def _cmd_spi_transfer(self, args: dict) -> None:
        device = self._device(args["oid"], "spi")
        self._send("spi_transfer_response", oid=device.oid, response=tmc_spi_transfer(device, args["data"]))

    def _cmd_spi_send(self, args: dict) -> None:
        tmc_spi_transfer(self._device(args["oid"], "spi"), args["data"])

    def _cmd_i2c_read(self, args: dict) -> None:
        device = self._device(args["oid"], "i2c")
        self._send("i2c_read_response", oid=device.oid, response=bytes(args["read_len"] & 0xFF))  # uint8_t data_len

    def _cmd_tmcuart_send(self, args: dict) -> None:
        device = self._device(args["oid"], "tmcuart")
        reply, read = tmc_uart_exchange(device, args["write"]), args["read"] & 0xFF
        if len(reply) != read:
            reply = b"\xff" * read  # nobody answered: the idle line, pulled high
        self._send("tmcuart_response", oid=device.oid, read=reply)

    def _cmd_neopixel_send(self, args: dict) -> None:
        device = self._device(args["oid"], "neopixel")
        self._send("neopixel_result", oid=device.oid, success=1)

    def _cmd_query_counter(self, args: dict) -> None:
        """src/pulse_counter.c: polled every poll_ticks from ``clock``; a poll after the next sample time
        reports (next_clock: the poll after it). The pin never changes, so only the reporting polls are run."""
        counter = self._device(args["oid"], "counter")
        poll, sample = args["poll_ticks"], args["sample_ticks"]
        if poll < self.chip.clocks(MIN_PERIOD_S):
            raise Shutdown(RESCHEDULED_IN_PAST)
        start = self.world_clock(args["clock"])
        self._add_timer(start + poll, self._counter_report, counter, start, poll, sample)

    def _counter_report(self, counter: Device, version: int, start: int, poll: int, sample: int) -> None:
        if version != counter.timer:
            return
        self._send("counter_state", oid=counter.oid, next_clock=self.mcu_clock(self.now + poll), count=0,
                   count_clock=0)
        polls = (self.now + sample - start) // poll + 1  # the first poll strictly after the next sample time
        self._add_timer(start + polls * poll, self._counter_report, counter, start, poll, sample)
