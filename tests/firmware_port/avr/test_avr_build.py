"""The AVR build itself: a clear one-line error without the toolchain, the RAM the ELF gives each law
against what the Python port declares, and the guard on deliberately wrong builds."""

from __future__ import annotations

import pytest

from firmware_port.avr import toolchain
from firmware_port.avr.build import ElfSpec, build_elf, inspect_elf
from firmware_port.avr.laws import LAWS, dtype
from firmware_port.fuzzy_pi import SEED004_HOTEND
from firmware_port.fuzzy_pi import ram_report as fuzzy_pi_ram
from firmware_port.fuzzy_pid import ram_report as fuzzy_pid_ram
from firmware_port.marlin.bangbang import BangBangBed
from firmware_port.marlin.pid import PidFixed

pytestmark = pytest.mark.avr


def test_without_the_toolchain_one_line_names_the_packages(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("CC", "no-such-compiler")
    monkeypatch.setattr(toolchain.sysconfig, "get_config_var", lambda name: None)
    monkeypatch.setattr(toolchain, "SIMAVR_INCLUDE_DIRS", (str(tmp_path),))
    toolchain.find_toolchain.cache_clear()
    try:
        with pytest.raises(toolchain.ToolchainMissing) as error:
            toolchain.find_toolchain()
    finally:
        toolchain.find_toolchain.cache_clear()
    message = str(error.value)
    assert "\n" not in message
    assert message.endswith("apt-get install gcc-avr avr-libc binutils-avr libsimavr-dev gcc")
    for part in ("gcc-avr (avr-gcc)", "binutils-avr", "libsimavr-dev", "gcc (a host C compiler"):
        assert part in message


# What the Python port says one heater keeps in RAM (state + configuration), per law.
DECLARED_RAM = {
    "pid": PidFixed.STATE_BYTES + PidFixed.GAIN_BYTES,
    "pid_in_band": PidFixed.STATE_BYTES + PidFixed.GAIN_BYTES,
    "bangbang_hotend": 0,
    "bangbang_bed": BangBangBed.STATE_BYTES,
    "bangbang_bed_limit": BangBangBed.STATE_BYTES,
    "fuzzy_pi": fuzzy_pi_ram(SEED004_HOTEND)["state_bytes"] + fuzzy_pi_ram(SEED004_HOTEND)["config_bytes"],
    "fuzzy_pid": fuzzy_pid_ram()["state_bytes"] + fuzzy_pid_ram()["config_bytes"],
}


@pytest.mark.parametrize("name", DECLARED_RAM)
def test_the_elf_keeps_the_ram_the_port_declares(name, avr_toolchain) -> None:
    law = LAWS[name]
    symbols = inspect_elf(build_elf(law.spec)).symbols
    assert sum(symbols[s][1] for s in ("law_state", "law_config") if s in symbols) == DECLARED_RAM[name]


@pytest.mark.parametrize("name", LAWS)
def test_the_records_match_the_c_structs(name, avr_toolchain) -> None:
    law = LAWS[name]
    symbols = inspect_elf(build_elf(law.spec)).symbols
    for symbol, fields in (("law_in", law.in_fields), ("law_out", law.out_fields),
                           ("law_state", law.state_fields), ("law_config", law.config_fields)):
        size = symbols[symbol][1] if symbol in symbols else 0
        assert size == dtype(fields).itemsize, symbol


def test_a_patch_must_match_exactly_once(avr_toolchain) -> None:
    with pytest.raises(ValueError, match="exactly once in pid.c"):
        build_elf(ElfSpec("glue_pid.c", ("pid.c",), patch=("pid.c", "no such text", "x")))
