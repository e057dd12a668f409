"""A law's ELF running in simavr, driven through the shim (harness/shim.c) with ctypes.

The host and the firmware talk through SRAM: the host writes a step's input into ``law_in`` and
``MAILBOX_RUN`` into ``mailbox``; the firmware runs the law and writes ``MAILBOX_IDLE`` back
(harness/main.c). Whole sequences of steps run inside the shim, so Python pays one call per
sequence, not per instruction.
"""

from __future__ import annotations

import ctypes
from functools import cache
from pathlib import Path

import numpy as np

from firmware_port.avr.build import ElfInfo, inspect_elf
from firmware_port.avr.toolchain import F_CPU_HZ, MCU, shim_path

MAILBOX_IDLE = 0xA5  # harness/main.c
MAILBOX_RUN = 0x01
STACK_PAINT = 0x5A
MARK_ADDR = 0x25  # PORTB in the data space: harness.h MARK_ON/MARK_OFF drive PB0
MARK_MASK = 0x01
BOOT_MAX_CYCLES = 1_000_000  # crt0 and main()'s stack painting take a few thousand
STEP_MAX_CYCLES = 10_000_000  # a law that runs longer than 0.6 s at 16 MHz is stuck
SHIM_ERRORS = {-1: "timed out", -2: "crashed", -3: "was given an address outside SRAM"}


class AvrError(RuntimeError):
    """The simulated MCU did not answer as the harness expects."""


@cache
def _shim() -> ctypes.CDLL:
    lib = ctypes.CDLL(str(shim_path()))
    ptr, u8, u16, u32, u64 = ctypes.c_void_p, ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_uint64
    lib.shim_open.restype, lib.shim_open.argtypes = ptr, [ctypes.c_char_p, ctypes.c_char_p, u32]
    lib.shim_close.restype, lib.shim_close.argtypes = None, [ptr]
    lib.shim_data.restype, lib.shim_data.argtypes = ptr, [ptr]
    lib.shim_ramend.restype, lib.shim_ramend.argtypes = u32, [ptr]
    lib.shim_wait.restype, lib.shim_wait.argtypes = ctypes.c_int, [ptr, u16, u8, u64]
    lib.shim_steps.restype = ctypes.c_int32
    lib.shim_steps.argtypes = [ptr, u16, u8, u8, u16, u16, ptr, u32, ptr, u8, ptr, u16, u8, ptr, u64]
    return lib


class AvrSim:
    """One simulated ATmega328P at 16 MHz running an ELF built on harness/main.c, booted."""

    def __init__(self, elf: Path):
        self.info: ElfInfo = inspect_elf(elf)
        self._lib = _shim()
        self._avr = self._lib.shim_open(str(elf).encode(), MCU.encode(), F_CPU_HZ)
        if not self._avr:
            raise AvrError(f"simavr could not load {elf}")
        size = self._lib.shim_ramend(self._avr) + 1
        self.ram = np.ctypeslib.as_array((ctypes.c_uint8 * size).from_address(self._lib.shim_data(self._avr)))
        self.mailbox = self.info.sram("mailbox")[0]
        self._check(self._lib.shim_wait(self._avr, self.mailbox, MAILBOX_IDLE, BOOT_MAX_CYCLES), "booting")

    def __repr__(self) -> str:
        return f"AvrSim({self.info.path.name}, {MCU} at {F_CPU_HZ / 1e6:g} MHz{'' if self._avr else ', closed'})"

    def close(self) -> None:
        if getattr(self, "_avr", None):  # also when __init__ failed half way
            self.ram = self.ram[:0]  # no view into the freed data space
            self._lib.shim_close(self._avr)
            self._avr = None

    def __del__(self) -> None:
        self.close()

    def write(self, symbol: str, data: bytes) -> None:
        """Fill an SRAM symbol (its full size) with ``data``."""
        address, size = self.info.sram(symbol)
        if len(data) != size:
            raise ValueError(f"{symbol} is {size} bytes, not {len(data)}")
        self.ram[address:address + size] = np.frombuffer(data, np.uint8)

    def read(self, symbol: str) -> bytes:
        address, size = self.info.sram(symbol)
        return self.ram[address:address + size].tobytes()

    def steps(self, inputs: np.ndarray, outputs: tuple[str, ...], out_dtype: np.dtype) -> tuple[np.ndarray, np.ndarray]:
        """Run one step per input record (written to ``law_in``); after each, the SRAM symbols
        ``outputs`` read back as one ``out_dtype`` record; and the cycles between the marks."""
        in_addr, in_size = self.info.sram("law_in")
        inputs = np.ascontiguousarray(inputs)
        if inputs.dtype.itemsize != in_size:
            raise ValueError(f"law_in is {in_size} bytes, the inputs {inputs.dtype.itemsize}")
        regions = np.array([self.info.sram(name) for name in outputs], np.uint16).ravel()
        if int(regions[1::2].sum()) != out_dtype.itemsize:
            raise ValueError(f"{', '.join(outputs)} take {int(regions[1::2].sum())} bytes, the record "
                             f"{out_dtype.itemsize}")
        n = len(inputs)
        out = np.zeros(n, out_dtype)
        cycles = np.zeros(n, np.uint32)
        done = self._lib.shim_steps(
            self._avr, self.mailbox, MAILBOX_RUN, MAILBOX_IDLE, in_addr, in_size, inputs.ctypes.data, n,
            regions.ctypes.data, len(outputs), out.ctypes.data, MARK_ADDR, MARK_MASK, cycles.ctypes.data,
            STEP_MAX_CYCLES,
        )
        self._check(done, "running a step")
        return out, cycles

    def peak_stack_address(self) -> int:
        """The lowest SRAM address written since boot above the end of .bss (main.c paints the rest)."""
        start = self.info.sram("__bss_end")[0]
        touched = np.flatnonzero(self.ram[start:] != STACK_PAINT)
        return start + int(touched[0])

    def _check(self, status: int, doing: str) -> None:
        if status < 0:
            raise AvrError(f"the simulated {MCU} {SHIM_ERRORS.get(status, f'failed ({status})')} while {doing}")
