"""A seeded G-code fuzzer for the virtual printer: lines a careless or hostile host could send.

``fuzz_lines(rng, n)`` draws lines from a grammar of the commands the printer knows (and some it
does not), with values from the everyday to the absurd (beyond float32, beyond int32, negative,
empty), line numbers and checksums right or wrong, and raw bytes. ``MARLIN_REPLY`` is every line
shape Marlin 2.1 (and the twin's heater port) prints; anything else on the wire is a defect.

Nightly-sized run (10^6 lines): ``FUZZ_LINES=1000000 python -m pytest tests/protocol/test_fuzz_serial.py``.
"""

from __future__ import annotations

import re

import numpy as np

from protocol.lines import with_checksum

CODES = ("G0", "G1", "G4", "G28", "G90", "G91", "G92", "M82", "M83", "M104", "M105", "M106", "M107", "M108",
         "M109", "M110", "M113", "M114", "M115", "M140", "M155", "M190", "M301", "M303", "M304", "M400",
         "M410", "M500", "M501", "M502", "M503", "M999", "G999", "M9999", "T0", "T1")
LETTERS = "SPRTEXYZFICDUN"
VALUES = ("", "0", "1", "-1", "200", "60", "255", "1.5", "-0.5", "99999999999999999999999999999999999999999",
          "-99999999999999999999999999999999999999999", "3.4e38", "1e38", "2147483647", "2147483648",
          "4294967295", "4294967296", "-2147483649", "65536", "32768", ".", "-", "+5", "0x10", "nan", "inf",
          "0.0001", "1e-30", "340282346638528859811704183484516925440")
# Marlin 2.1's replies (and the heater port's messages), one regex per shape; a target can be
# negative (setTargetHotend() clamps only from above: M104 S-1 reports /-1.00).
MARLIN_REPLY = re.compile("|".join((
    r"ok( T:.*)?",
    r" T:-?\d+\.\d\d /-?\d+\.\d\d( B:-?\d+\.\d\d /-?\d+\.\d\d)? @:\d+( B@:\d+)?( W:(\?|\d+))?",
    r"echo:.*",
    r"Error:.*",
    r"Resend: -?\d+",
    r"X:\S+ Y:\S+ Z:\S+ E:\S+ Count X:-?\d+ Y:-?\d+ Z:-?\d+",
    r"FIRMWARE_NAME:Marlin .*",
    r"Cap:[A-Z0-9_]+:[01]",
    r"start|PowerUp| External Reset|Marlin 2\.1\.2\.1",
    r"PID Autotune .*",
    r" bias: .*| Classic PID ?| No overshoot| Kp: .*",
    r"#define DEFAULT_(bed)?K[pid] .*",
    r"Printer stopped due to errors\..*",
)))


def _word(rng: np.random.Generator) -> str:
    letter = LETTERS[rng.integers(len(LETTERS))]
    return letter + VALUES[rng.integers(len(VALUES))]


def fuzz_line(rng: np.random.Generator, last_n: int) -> bytes:
    """One line, its end of line included."""
    kind = rng.random()
    if kind < 0.05:  # raw bytes, any of them
        return bytes(rng.integers(0, 256, rng.integers(1, 120), dtype=np.uint8)) + b"\n"
    words = [CODES[rng.integers(len(CODES))]] + [_word(rng) for _ in range(rng.integers(0, 5))]
    text = " ".join(words)
    if kind < 0.15:
        text = text + " ;" + "comment"
    if kind > 0.7:  # numbered, mostly right
        n = last_n + 1 if rng.random() < 0.8 else int(rng.integers(-5, 2**31 - 1))
        framed = with_checksum(text, n)
        if rng.random() < 0.1:
            framed = framed[:-1] + str(rng.integers(10))
        text = framed
    return text.encode("latin-1") + (b"\n" if rng.random() < 0.9 else b"\r")


def fuzz_lines(seed: int, n_lines: int):
    """``n_lines`` lines from a seeded generator (same seed, same lines)."""
    rng = np.random.default_rng(seed)
    last_n = 0
    for _ in range(n_lines):
        line = fuzz_line(rng, last_n)
        if line.startswith(b"N"):
            last_n += 1
        yield line


def bad_replies(text: str) -> list[str]:
    """Lines of the printer's output that are not Marlin-shaped."""
    return [line for line in text.split("\n") if line and not MARLIN_REPLY.fullmatch(line)]
