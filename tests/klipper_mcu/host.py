"""A host for the twin MCU in a test: it frames commands with klippy's sequence numbers, hands
them to the MCU at chosen world clocks, and decodes every response block. No wall clock."""

from __future__ import annotations

from protocol.klipper_mcu.board import TwinBoard
from protocol.klipper_mcu.codec import MESSAGE_SEQ_MASK, BlockReader, frame, parse_messages
from protocol.klipper_mcu.dictionary import CLOCK_FREQ, Dictionary, build_dictionary, pin_number
from protocol.klipper_mcu.mcu import KlipperMcu
from twin.scenario import parse_scenario

NO_SCENARIO = parse_scenario('name = "test"\nduration_s = 86400\n', "test")
S = CLOCK_FREQ  # clocks per second


class TestHost:
    """Sends commands (``send``) and collects the responses as (name, params) pairs (``responses``)."""

    __test__ = False  # not a pytest class

    def __init__(self, board: TwinBoard | None = None, *, strict: bool = False, dictionary: Dictionary | None = None):
        self.dictionary = dictionary or build_dictionary("test")
        self.board = board or TwinBoard(NO_SCENARIO)
        self.mcu = KlipperMcu(self.board, self.dictionary, strict=strict)
        self.sequence = 0
        self.responses: list[tuple[str, dict]] = []
        self.acks = 0
        self._reader = BlockReader()
        self._by_id = {f.msg_id: f for f in self.dictionary.responses.values()}

    def send(self, clock: int, *commands: str, **data: bytes) -> None:
        """Commands in one block ("name key=value ..."), arriving at world clock ``clock``; ``data``: the
        byte-string arguments (%*s fields) of a single command."""
        payload = b""
        for command in commands:
            name, *args = command.split()
            values: dict[str, int | bytes] = {key: int(value) for key, value in (arg.split("=") for arg in args)}
            fmt = self.dictionary.commands[name]
            payload += fmt.encode(**values, **data)
        self.raw(clock, frame(self.sequence, payload))
        self.sequence = (self.sequence + 1) & MESSAGE_SEQ_MASK

    def raw(self, clock: int, data: bytes) -> None:
        self.mcu.receive(data, clock)
        self._collect()

    def run(self, clock: int) -> None:
        self.mcu.run_until(clock)
        self._collect()

    def named(self, name: str) -> list[dict]:
        return [params for got, params in self.responses if got == name]

    def configure(self, clock: int = 0, *, max_duration_s: float = 5.0) -> None:
        """klippy 0.12's heater-only configuration: oid 0 the hotend's ADC (PK5), oid 1 its heater (PB4)
        as a soft PWM of 0.1 s cycles; no query yet."""
        self.send(clock, "allocate_oids count=2", f"config_analog_in oid=0 pin={pin_number('PK5')}",
                  f"config_digital_out oid=1 pin={pin_number('PB4')} value=0 default_value=0 max_duration={int(max_duration_s * S)}",
                  f"set_digital_out_pwm_cycle oid=1 cycle_ticks={S // 10}", "finalize_config crc=1234")

    def _collect(self) -> None:
        for block in self._reader.feed(self.mcu.take_output()):
            assert block is not None, "the MCU sent a corrupt block"
            if not block.payload:
                self.acks += 1
            for fmt, params in parse_messages(block.payload, self._by_id):
                self.responses.append((fmt.name, params))
