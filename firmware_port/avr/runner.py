"""A law's AVR build in simavr, and the differential check against its Python port.

``LawSim`` runs sequences of input records through the compiled law and returns, after every
step, its output and state as one record. ``compare`` runs the same sequence through the Python
port and returns the first step where any field differs (None: equal bit for bit throughout).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from firmware_port.avr.build import ElfSpec, build_elf
from firmware_port.avr.laws import OP_INIT, OP_RESET, OP_STEP, Law, dtype
from firmware_port.avr.sim import AvrSim


class LawSim:
    """One law's ELF (or a variant of its build) booted in simavr."""

    def __init__(self, law: Law, spec: ElfSpec | None = None):
        self.law = law
        self.sim = AvrSim(build_elf(spec or law.spec))
        self.in_dtype = dtype(law.in_fields)
        self.record_dtype = dtype(law.record_fields)

    def __repr__(self) -> str:
        return f"LawSim({self.law.name!r}, elf={self.sim.info.path.name})"

    def inputs(self, records: Sequence[tuple]) -> np.ndarray:
        """Input records (tuples in law_in's field order) as the array ``run`` takes."""
        return np.array(list(records), self.in_dtype)

    def configure(self, port: Any) -> None:
        """Write the port's configuration into law_config (what M301 and friends store)."""
        if self.law.config_fields:
            self.sim.write("law_config", np.array([self.law.config(port)], dtype(self.law.config_fields)).tobytes())

    def load_state(self, port: Any) -> None:
        """Write the port's state into law_state."""
        if self.law.state_fields:
            self.sim.write("law_state", np.array([self.law.state(port)], dtype(self.law.state_fields)).tobytes())

    def read_state(self) -> dict[str, int]:
        """law_state as the MCU holds it now, by field."""
        if not self.law.state_fields:
            return {}
        record = np.frombuffer(self.sim.read("law_state"), dtype(self.law.state_fields))[0]
        return dict(zip(record.dtype.names or (), record.tolist()))

    def run(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step per input record: the records after each step, and the cycles of each call
        (0 for an init or a reset, which run outside the marks)."""
        return self.sim.steps(inputs, self.law.symbols, self.record_dtype)

    def op(self, op: int) -> np.ndarray:
        """Run one OP_INIT or OP_RESET; the record after it."""
        record = np.zeros(1, self.in_dtype)
        record["op"] = op
        return self.run(record)[0][0]

    def close(self) -> None:
        self.sim.close()


def run_port(law: Law, settings: Any, records: Sequence[tuple]) -> list[tuple]:
    """The Python port (``law.port(settings)``) on input records: after each step its outputs
    (zeros after an init or a reset, as the glue writes) and state, as one flat tuple."""
    zeros = (0,) * len(law.out_fields)
    port = law.port(settings)
    rows = []
    for record in records:
        if record[0] == OP_STEP:
            rows.append(law.step(port, record) + law.state(port))
            continue
        if record[0] == OP_INIT:
            port = law.port(settings)
        elif record[0] == OP_RESET:
            port.reset()
        rows.append(zeros + law.state(port))
    return rows


@dataclass(frozen=True)
class Mismatch:
    """The first step where the AVR build and the Python port differ."""

    step: int
    inputs: dict[str, int]
    avr: dict[str, int]
    port: dict[str, int]

    def __str__(self) -> str:
        fields = ", ".join(f"{k} avr {self.avr[k]} port {self.port[k]}" for k in self.avr if self.avr[k] != self.port[k])
        given = ", ".join(f"{k} {v}" for k, v in self.inputs.items())
        return f"step {self.step} ({given}): {fields}"


def compare(law_sim: LawSim, settings: Any, records: Sequence[tuple]) -> Mismatch | None:
    """Power up both sides (the AVR's init, the port ``law.port(settings)``), configure the AVR
    from the port, run ``records`` through both and compare every field after every step, the
    power-up state included (step 0)."""
    law = law_sim.law
    law_sim.configure(law.port(settings))
    records = [law.init_record, *records]
    avr_rows = law_sim.run(law_sim.inputs(records))[0].tolist()
    port_rows = run_port(law, settings, records)
    names = [name for name, _ in law.record_fields]
    in_names = [name for name, _ in law.in_fields]
    for step, (got, want) in enumerate(zip(avr_rows, port_rows)):
        if got != want:
            return Mismatch(step, dict(zip(in_names, records[step])), dict(zip(names, got)), dict(zip(names, want)))
    return None
