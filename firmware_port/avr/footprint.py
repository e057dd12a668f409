"""What each law costs on the ATmega328P: flash and RAM from the ELF, stack and cycles measured in simavr.

- flash: the law's ELF minus the empty board's (harness/glue_none.c): the law's code, its
  tables in PROGMEM, the libgcc helpers it pulls in (64-bit multiply and shifts, 32-bit
  division) and its glue call;
- RAM: law_state + law_config, the bytes one heater keeps (avr-nm sizes);
- stack: how much deeper the stack goes than the empty board's, painted at boot (main.c);
- cycles: simavr's cycle counter between the two PB0 writes around the call, minus the same
  for nothing between them, over a seeded workload; the worst case against one period of
  Marlin's temperature ISR at 16 MHz (16,384 cycles at 976.5625 Hz).
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from fractions import Fraction
from functools import cache

import numpy as np

from firmware_port.avr.build import build_elf, inspect_elf
from firmware_port.avr.laws import BASELINE, LAWS, OP_STEP, AdcLaw, Law, SoftPwmLaw, ThermistorLaw, dtype
from firmware_port.avr.runner import LawSim
from firmware_port.avr.sim import AvrSim
from firmware_port.avr.toolchain import F_CPU_HZ
from firmware_port.marlin.constants import ISR_HZ, SOFT_PWM_MAX, TICKS_PER_READING
from firmware_port.thermistor import ADC_MAX, MAX_RAW_THERMISTOR_VALUE, TEMP_ONE

CYCLES_PER_ISR = int(Fraction(F_CPU_HZ) / ISR_HZ)  # 16384: one temperature-ISR period at 16 MHz
WALK_TARGETS_C = (50, 250)  # walks are drawn around a target in this range
WALK_SPAN_C = 15  # ... staying within this of it (the PID band is +-10 degC)
WALK_STEP_Q5 = 64  # ... moving up to 2 degC a sample


@dataclass(frozen=True)
class Footprint:
    law: str
    title: str
    period_isrs: int  # Marlin calls the law once every this many ISRs
    flash_bytes: int
    ram_bytes: int
    stack_bytes: int
    calls: int
    cycles_min: int
    cycles_median: float
    cycles_max: int

    @property
    def isr_share(self) -> float:
        """The worst call as a fraction of one temperature-ISR period at 16 MHz."""
        return self.cycles_max / CYCLES_PER_ISR

    @property
    def cpu_share(self) -> float:
        """The worst call as a fraction of the CPU at the rate Marlin calls the law."""
        return self.isr_share / self.period_isrs

    @property
    def max_us(self) -> float:
        return self.cycles_max / F_CPU_HZ * 1e6


def walk(rng: random.Random, steps: int) -> list[tuple]:
    """A controller's inputs: a temperature walk around a target, reflected at +-WALK_SPAN_C, so a
    PID sees its band (about two thirds of the calls) and the bang-bang zone beyond."""
    target_c = rng.randint(*WALK_TARGETS_C)
    span_q5 = WALK_SPAN_C * TEMP_ONE
    offset_q5 = rng.randint(-span_q5, span_q5)
    records = []
    for _ in range(steps):
        offset_q5 += rng.randint(-WALK_STEP_Q5, WALK_STEP_Q5)
        if abs(offset_q5) > span_q5:
            offset_q5 = 2 * (span_q5 if offset_q5 > 0 else -span_q5) - offset_q5
        records.append((OP_STEP, target_c * TEMP_ONE + offset_q5, target_c))
    return records


def workload(law: Law, rng: random.Random, sequences: int, steps: int) -> list[list[tuple]]:
    """The input sequences a law's cycles are measured on (each starts from power-up)."""
    if isinstance(law, ThermistorLaw):  # every raw value
        return [[(OP_STEP, raw) for raw in range(MAX_RAW_THERMISTOR_VALUE + 1)]]
    if isinstance(law, AdcLaw):  # ISRs with the main loop taking every reading
        return [[(OP_STEP, 1, rng.randint(0, ADC_MAX), rng.randint(0, ADC_MAX)) for _ in range(steps)]
                for _ in range(sequences)]
    if isinstance(law, SoftPwmLaw):  # ISRs with new amounts on every reading
        return [[(OP_STEP, 3 if i % TICKS_PER_READING == 0 else 0, rng.randint(0, SOFT_PWM_MAX),
                  rng.randint(0, SOFT_PWM_MAX)) for i in range(steps)] for _ in range(sequences)]
    return [walk(rng, steps) for _ in range(sequences)]


@cache
def _baseline() -> tuple[int, int, int]:
    """The empty board: flash, the lowest stack address after one step, the marker's own cycles."""
    sim = AvrSim(build_elf(BASELINE))
    _, cycles = sim.steps(np.zeros(1, dtype((("op", "u1"),))), (), np.dtype([]))
    lowest = sim.peak_stack_address()
    sim.close()
    return inspect_elf(sim.info.path).flash_bytes, lowest, int(cycles[0])


def measure(law: Law, rng: random.Random, sequences: int, steps: int) -> Footprint:
    """One law's footprint over its workload, in its default configuration (``law.port()``)."""
    base_flash, base_lowest, base_cycles = _baseline()
    law_sim = LawSim(law)
    law_sim.configure(law.port())
    cycles = []
    for records in workload(law, rng, sequences, steps):
        inputs = law_sim.inputs([law.init_record, *records])
        cycles.append(law_sim.run(inputs)[1][1:])
    lowest = law_sim.sim.peak_stack_address()
    info = law_sim.sim.info
    law_sim.close()
    ram = sum(info.symbols[name][1] for name in ("law_state", "law_config") if name in info.symbols)
    counts = np.concatenate(cycles).astype(np.int64) - base_cycles
    return Footprint(law.name, law.title, law.period_isrs, info.flash_bytes - base_flash, ram, base_lowest - lowest, len(counts),
                     int(counts.min()), float(np.median(counts)), int(counts.max()))


def measure_all(seed: int, sequences: int, steps: int) -> list[Footprint]:
    """Every law, each on its own stream of the seed."""
    return [measure(law, random.Random(f"{seed}:{law.name}"), sequences, steps) for law in LAWS.values()]
