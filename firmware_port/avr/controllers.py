"""Controllers whose update() runs the compiled law in simavr: the machine code in the loop.

``on_avr(controller)`` takes a Python controller of the port (PidFixed, BangBangHotend,
BangBangBed, FuzzyPi, FuzzyPid) and returns a controller with the same ``Controller`` protocol
whose state lives in a simulated ATmega328P: each ``update`` is one call of the C law. The Python
object stays behind as the configuration only (it turns M301 gains into the Q integers written
into law_config, as its ``set_gains`` does); it is never stepped. ``twin-sim --engine avr`` and
``Twin(..., engine="avr")`` put these in the board in place of the firmware's own.
"""

from __future__ import annotations

from typing import Any

from firmware_port.avr.laws import OP_RESET, OP_STEP, law_for
from firmware_port.avr.runner import LawSim
from firmware_port.controller import Controller, Tunable, is_tunable
from firmware_port.marlin.pid import PidGains


class AvrController:
    """A Controller stepped in simavr, starting from the state of the Python controller it mirrors."""

    def __init__(self, controller: Controller):
        self.law = law_for(controller)
        self._config = controller
        self._sim = LawSim(self.law)
        self._sim.configure(controller)
        self._sim.load_state(controller)
        self._step = self._sim.inputs([(OP_STEP, 0, 0)])

    @property
    def check_interval_ms(self) -> int | None:
        return self._config.check_interval_ms

    def reset(self) -> None:
        self._sim.op(OP_RESET)

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """One call of the C law on a fresh reading; the output 0..255."""
        self._step["temp_q5"] = temp_q5
        self._step["target_c"] = target_c
        record = self._sim.run(self._step)[0][0]
        return self.law.counts(record.tolist())

    def state(self) -> dict[str, int]:
        """The law's state as the MCU holds it now."""
        return self._sim.read_state()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.law.title}, in simavr, mirroring {self._config!r})"


class AvrTunable(AvrController):
    """An AvrController that takes PID gains (M301/M304, M303 U1), like the controller it mirrors."""

    def __init__(self, controller: Tunable):
        super().__init__(controller)
        self._tunable = controller

    @property
    def gains(self) -> PidGains:
        return self._tunable.gains

    def set_gains(self, gains: PidGains) -> None:
        """Scale the gains as the port does, write them into law_config, and reset the loop."""
        self._tunable.set_gains(gains)
        self._sim.configure(self._tunable)
        self.reset()


def on_avr(controller: Any) -> AvrController:
    """The AVR build of a Python controller, in its current state; ValueError if it has none."""
    return AvrTunable(controller) if is_tunable(controller) else AvrController(controller)
