"""Klipper's binary MCU protocol on the wire: message blocks, VLQ integers and message formats.

A block is ``length, sequence, payload, crc16 (2 bytes, big end first), 0x7e``, 5 to 64 bytes
(Klipper's docs/Protocol.md, src/command.c). The sequence byte is ``0x10 | seq & 0x0f``. The
payload holds messages: a one-byte message id, then each parameter as a VLQ integer (a
two's-complement int32 in 7-bit groups, high first) or as a length byte and the bytes.
An empty block is an ack (or a nak) carrying the sequence number the MCU expects next.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

MESSAGE_MIN = 5  # an empty block: length, sequence, crc (2), sync
MESSAGE_MAX = 64
MESSAGE_HEADER_SIZE = 2
MESSAGE_TRAILER_SIZE = 3
MESSAGE_PAYLOAD_MAX = MESSAGE_MAX - MESSAGE_MIN
MESSAGE_SEQ_MASK = 0x0F
MESSAGE_DEST = 0x10
MESSAGE_SYNC = 0x7E
INT_FORMATS = ("%u", "%i", "%hu", "%hi", "%c")  # all VLQ on the wire
BUFFER_FORMATS = ("%s", "%.*s", "%*s")  # a length byte, then the bytes


class ProtocolError(ValueError):
    """A message that cannot be encoded or parsed (the MCU answers it with "Command parser error")."""


class UnknownMessage(ProtocolError):
    """A message id the dictionary lacks (the MCU answers it with "Invalid command")."""


def crc16_ccitt(data: bytes | bytearray) -> int:
    """The block checksum (CRC-16/CCITT as Klipper computes it: init 0xffff, reflected update)."""
    crc = 0xFFFF
    for byte in data:
        byte ^= crc & 0xFF
        byte ^= (byte << 4) & 0xFF
        crc = ((byte << 8) | (crc >> 8)) ^ (byte >> 4) ^ (byte << 3)
    return crc & 0xFFFF


def encode_vlq(value: int, out: bytearray) -> None:
    """Append ``value`` (int32 or uint32) as Klipper's variable-length quantity: as few 7-bit groups
    as hold it, continuation bit 0x80 on all but the last; the first group's bits 0x60 sign-extend."""
    if not -(1 << 31) <= value < 1 << 32:
        raise ProtocolError(f"integer {value} does not fit in 32 bits")
    signed = value - (1 << 32) if value >= 1 << 31 else value
    groups = 1
    while not -(1 << (5 + 7 * (groups - 1))) <= signed < 3 << (5 + 7 * (groups - 1)) and groups < 5:
        groups += 1
    unsigned = signed & 0xFFFFFFFF  # the top group of five is then 0..15, as src/command.c writes it
    for shift in range(7 * (groups - 1), 0, -7):
        out.append((unsigned >> shift) & 0x7F | 0x80)
    out.append(unsigned & 0x7F)


def decode_vlq(data: bytes | bytearray, pos: int) -> tuple[int, int]:
    """(uint32 value, next position) of the VLQ at ``pos``; ProtocolError if the data ends first."""
    try:
        byte = data[pos]
        value = byte & 0x7F
        if byte & 0x60 == 0x60:
            value |= -0x20
        while byte & 0x80:
            pos += 1
            byte = data[pos]
            value = (value << 7) | (byte & 0x7F)
    except IndexError:
        raise ProtocolError("message ends inside an integer") from None
    return value & 0xFFFFFFFF, pos + 1


def to_signed(value: int, bits: int = 32) -> int:
    """A decoded uint32 read as a two's-complement integer of ``bits`` bits (``%i``, ``%hi``)."""
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


@dataclass(frozen=True)
class MessageFormat:
    """One command or response: its format string exactly as the data dictionary spells it
    (``"queue_digital_out oid=%c clock=%u on_ticks=%u"``) and its message id."""

    text: str
    msg_id: int

    def __post_init__(self) -> None:
        if not 0 <= self.msg_id <= 0x7F:
            raise ProtocolError(f"message id {self.msg_id} of {self.name!r} is not one byte")
        for _, fmt in self.params:
            if fmt not in INT_FORMATS + BUFFER_FORMATS:
                raise ProtocolError(f"unknown parameter type {fmt!r} in {self.text!r}")

    @property
    def name(self) -> str:
        return self.text.split()[0]

    @property
    def params(self) -> list[tuple[str, str]]:
        """(name, printf type) of each parameter, in order."""
        return [tuple(part.split("=", 1)) for part in self.text.split()[1:]]  # type: ignore[misc]

    def encode(self, **values: int | bytes) -> bytes:
        """The message's bytes: its id, then each parameter (ints as VLQ, bytes as length + bytes)."""
        out = bytearray((self.msg_id,))
        for name, fmt in self.params:
            value = values[name]
            if fmt in BUFFER_FORMATS:
                data = bytes(value)
                if len(data) > 0xFF:
                    raise ProtocolError(f"{self.name}: {name} is {len(data)} bytes, more than a length byte counts")
                out.append(len(data))
                out += data
            else:
                encode_vlq(int(value), out)
        return bytes(out)

    def decode(self, data: bytes | bytearray, pos: int, end: int | None = None) -> tuple[dict[str, int | bytes], int]:
        """The parameters that start at ``data[pos]`` (just after the message id), and the position after them.

        As src/command.c command_parsef reads them: a parameter must start at or before ``end`` (default
        the data's end) and a buffer must end by it, while an integer is read on until a byte without the
        continuation bit, past ``end`` if need be. Integers come back as uint32 (see ``to_signed``)."""
        end = len(data) if end is None else end
        values: dict[str, int | bytes] = {}
        for name, fmt in self.params:
            if pos > end:
                raise ProtocolError(f"{self.name}: {name} starts past the end of the block")
            if fmt in BUFFER_FORMATS:
                if pos >= len(data) or pos + 1 + data[pos] > end:
                    raise ProtocolError(f"{self.name}: {name} runs past the end of the block")
                values[name] = bytes(data[pos + 1:pos + 1 + data[pos]])
                pos += 1 + data[pos]
            else:
                values[name], pos = decode_vlq(data, pos)
        return values, pos


def frame(sequence: int, payload: bytes | bytearray = b"") -> bytes:
    """One block around ``payload`` (empty: an ack/nak) with the sequence number ``sequence``."""
    length = MESSAGE_MIN + len(payload)
    if length > MESSAGE_MAX:
        raise ProtocolError(f"payload of {len(payload)} bytes does not fit in one block")
    head = bytes((length, MESSAGE_DEST | (sequence & MESSAGE_SEQ_MASK))) + bytes(payload)
    crc = crc16_ccitt(head)
    return head + bytes((crc >> 8, crc & 0xFF, MESSAGE_SYNC))


class Block(NamedTuple):
    """A block that passed the length, destination, sync and CRC checks."""

    sequence: int  # 0..15
    payload: bytes
    trailer: bytes = b""  # CRC and sync: the MCU's parser may read an integer on into them


class BlockReader:
    """Finds blocks in the byte stream as the MCU does (src/command.c command_find_block).

    ``feed`` yields each valid block, and ``NAK`` where the MCU would send a nak for garbage: on
    a bad block it drops bytes up to the next sync byte and asks for a resend once, until a valid
    block comes; leading sync bytes are skipped silently."""

    NAK = None

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._need_sync = False
        self._naked = False  # a nak went out for garbage since the last valid block

    def __repr__(self) -> str:
        return f"BlockReader({len(self._buffer)} bytes waiting)"

    def feed(self, data: bytes) -> Iterator[Block | None]:
        self._buffer += data
        while self._buffer:
            if self._need_sync:
                if not self._drop_to_sync():
                    return
                continue
            status = self._check()
            if status == 0:
                return
            if status > 0:
                self._naked = False
                block = bytes(self._buffer[:status])
                del self._buffer[:status]
                yield Block(block[1] & MESSAGE_SEQ_MASK, block[MESSAGE_HEADER_SIZE:-MESSAGE_TRAILER_SIZE],
                            block[-MESSAGE_TRAILER_SIZE:])
                continue
            if self._buffer[0] == MESSAGE_SYNC:
                del self._buffer[:1]
                continue
            self._need_sync = True
            if not self._naked:
                self._naked = True
                yield self.NAK

    def _drop_to_sync(self) -> bool:
        """Discard up to and including the next sync byte; False if none has come yet."""
        at = self._buffer.find(MESSAGE_SYNC)
        if at < 0:
            self._buffer.clear()
            return False
        del self._buffer[:at + 1]
        self._need_sync = False
        return True

    def _check(self) -> int:
        """The length of a valid block at the start, 0 if more bytes are needed, -1 if it is bad."""
        buf = self._buffer
        if len(buf) < MESSAGE_MIN:
            return 0
        length = buf[0]
        if not MESSAGE_MIN <= length <= MESSAGE_MAX or buf[1] & ~MESSAGE_SEQ_MASK != MESSAGE_DEST:
            return -1
        if len(buf) < length:
            return 0
        if buf[length - 1] != MESSAGE_SYNC:
            return -1
        crc = crc16_ccitt(buf[:length - MESSAGE_TRAILER_SIZE])
        if (buf[length - 3] << 8 | buf[length - 2]) != crc:
            return -1
        return length


def parse_messages(payload: bytes, formats: dict[int, MessageFormat]) -> list[tuple[MessageFormat,
                                                                                   dict[str, int | bytes]]]:
    """Every message in a response block's payload (one-byte ids), in order; ProtocolError on an
    unknown id or a message cut short."""
    out = []
    pos = 0
    while pos < len(payload):
        fmt = formats.get(payload[pos])
        if fmt is None:
            raise UnknownMessage(f"unknown message id {payload[pos]}")
        values, pos = fmt.decode(payload, pos + 1)
        out.append((fmt, values))
    return out


def iter_commands(block: Block, formats: dict[int, MessageFormat]) -> Iterator[tuple[MessageFormat,
                                                                                    dict[str, int | bytes]]]:
    """The commands of a host block one at a time, as src/command.c command_dispatch reads them (the
    MCU runs each before it reads the next): a message id of one byte, or two when the first has
    0x80 set (``(first & 0x7f) << 7 | second``), then its parameters (``MessageFormat.decode``, the
    trailer readable). UnknownMessage for an id it lacks ("Invalid command"), ProtocolError for a
    parameter past the end ("Command parser error")."""
    data = block.payload + block.trailer
    end = len(block.payload)
    pos = 0
    while pos < end:
        msg_id = data[pos]
        pos += 1
        if msg_id & 0x80:
            msg_id = ((msg_id & 0x7F) << 7) | data[pos]
            pos += 1
        fmt = formats.get(msg_id)
        if fmt is None:
            raise UnknownMessage(f"unknown command id {msg_id}")
        values, pos = fmt.decode(data, pos, end)
        yield fmt, values
