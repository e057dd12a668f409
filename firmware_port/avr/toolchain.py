"""The AVR toolchain: find avr-gcc, binutils-avr, avr-libc and libsimavr, and build into a cache.

Builds are keyed by everything that goes into them (sources, generated headers, flags, compiler
version), so a changed source rebuilds and an unchanged one costs a hash. The cache is
``$HEATER_TWIN_AVR_CACHE``, else ``$XDG_CACHE_HOME/heater-twin/avr``, else
``~/.cache/heater-twin/avr``; each build is written to a temporary folder and renamed into place,
so concurrent runs never see half a build.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sysconfig
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from firmware_port.user_cache import user_cache_dir

MCU = "atmega328p"
F_CPU_HZ = 16_000_000  # the ATmega328P of an Arduino-class printer board, Marlin's 16 MHz
# The Debian/Ubuntu packages (apt-get install -y --no-install-recommends ...); the shim also needs a
# host C compiler (gcc).
APT_PACKAGES = ("gcc-avr", "avr-libc", "binutils-avr", "libsimavr-dev", "gcc")
AVR_CFLAGS = ("-mmcu=" + MCU, "-Os", "-Wall", "-Werror", "-ffunction-sections", "-fdata-sections")
AVR_LDFLAGS = ("-Wl,--gc-sections",)
SHIM_CFLAGS = ("-O2", "-shared", "-fPIC", "-Wall", "-Werror")
SIMAVR_INCLUDE_DIRS = ("/usr/include/simavr", "/usr/local/include/simavr")
HERE = Path(__file__).resolve().parent
SRC_DIR = HERE / "src"
HARNESS_DIR = HERE / "harness"
SRAM_OFFSET = 0x800000  # avr-nm's address of data-space byte 0


class ToolchainMissing(OSError):
    """The AVR toolchain or libsimavr is not installed; the message (one line) names the packages.

    An OSError, like a missing file: CLIs report it on one line with their other environment errors.
    """


@dataclass(frozen=True)
class Toolchain:
    avr_gcc: str
    avr_size: str
    avr_nm: str
    host_cc: str
    simavr_include: Path

    @property
    def version(self) -> str:
        """The compiler's first ``--version`` line, e.g. ``avr-gcc (GCC) 5.4.0``."""
        return _compiler_version(self.avr_gcc)


@cache
def find_toolchain() -> Toolchain:
    """The installed toolchain; ToolchainMissing (one line naming the packages) if a part is absent."""
    missing = []
    found = {name: shutil.which(name) for name in ("avr-gcc", "avr-size", "avr-nm")}
    host_cc = next((cc for cc in (os.environ.get("CC"), sysconfig.get_config_var("CC"), "cc", "gcc")
                    if cc and shutil.which(cc.split()[0])), None)
    if found["avr-gcc"] is None:
        missing.append("gcc-avr (avr-gcc)")
    elif not _has_avr_libc(found["avr-gcc"]):
        missing.append("avr-libc (avr/io.h)")
    if found["avr-size"] is None or found["avr-nm"] is None:
        missing.append("binutils-avr (avr-size, avr-nm)")
    include = next((Path(d) for d in SIMAVR_INCLUDE_DIRS if (Path(d) / "sim_avr.h").is_file()), None)
    if include is None:
        missing.append("libsimavr-dev (sim_avr.h)")
    if host_cc is None:
        missing.append("gcc (a host C compiler for the simavr shim)")
    if missing:
        raise ToolchainMissing(f"the AVR toolchain is missing {', '.join(missing)}: apt-get install {' '.join(APT_PACKAGES)}")
    assert include is not None and host_cc is not None
    return Toolchain(str(found["avr-gcc"]), str(found["avr-size"]), str(found["avr-nm"]), host_cc, include)


@cache
def _compiler_version(avr_gcc: str) -> str:
    return subprocess.run([avr_gcc, "--version"], capture_output=True, text=True, check=True).stdout.splitlines()[0]


def _has_avr_libc(avr_gcc: str) -> bool:
    probe = subprocess.run([avr_gcc, "-mmcu=" + MCU, "-print-file-name=libc.a"], capture_output=True, text=True)
    return probe.returncode == 0 and os.path.isabs(probe.stdout.strip())


def cache_dir() -> Path:
    override = os.environ.get("HEATER_TWIN_AVR_CACHE")
    if override:
        return Path(override)
    return user_cache_dir() / "avr"


class BuildError(RuntimeError):
    """A compiler or linker refused the sources; the message carries its output."""


def cached_build(kind: str, inputs: Sequence[bytes], output: str, build: Callable[[Path], None]) -> Path:
    """The cached ``output`` file of a build keyed by ``inputs``; ``build(folder)`` makes it on a miss."""
    key = hashlib.sha256(b"\0".join(inputs)).hexdigest()[:20]
    final = cache_dir() / f"{kind}-{key}"
    if (final / output).is_file():
        return final / output
    final.parent.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{kind}-"))
    try:
        build(folder)
        try:
            os.replace(folder, final)
        except OSError:  # a concurrent build got there first: theirs is the same
            if not (final / output).is_file():
                raise
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return final / output


def run_compiler(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise BuildError(f"{' '.join(command)}\n{done.stdout}{done.stderr}")


def shim_path() -> Path:
    """The shared library on libsimavr that firmware_port/avr/sim.py drives, built on first use."""
    tools = find_toolchain()
    source = HARNESS_DIR / "shim.c"
    sim_avr_h = tools.simavr_include / "sim_avr.h"
    inputs = [source.read_bytes(), sim_avr_h.read_bytes(), tools.host_cc.encode(), *(f.encode() for f in SHIM_CFLAGS)]

    def build(folder: Path) -> None:
        run_compiler([*tools.host_cc.split(), *SHIM_CFLAGS, f"-I{tools.simavr_include}", str(source),
                      "-o", str(folder / "shim.so"), "-lsimavr"])

    return cached_build("shim", inputs, "shim.so", build)
