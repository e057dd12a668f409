"""twin-firmware-report's AVR table: printed, written into a page between its markers, and a clear
line instead when the toolchain is missing."""

from __future__ import annotations

import re

import pytest

from firmware_port.avr import toolchain
from firmware_port.avr.laws import LAWS
from tools.cli.firmware_report import AVR_DOC_BEGIN, AVR_DOC_END, main

SMALL = ["--sequences", "2", "--steps", "20"]


@pytest.mark.avr
def test_the_avr_table_is_printed_and_written_into_the_page(capsys, tmp_path, avr_toolchain) -> None:
    page = tmp_path / "firmware.md"
    page.write_text(f"# Firmware\n\n{AVR_DOC_BEGIN} (twin-firmware-report --doc) -->\nold\n{AVR_DOC_END}\n\nafter\n")
    assert main([*SMALL, "--doc", str(page)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^AVR build \(avr-gcc .*-mmcu=atmega328p -Os -Wall -Werror", out, re.M)
    text = page.read_text()
    assert "old" not in text and text.endswith(f"{AVR_DOC_END}\n\nafter\n")
    assert f"Written by `twin-firmware-report {' '.join(SMALL)} --doc {page}`" in text
    for name in LAWS:
        row = re.search(rf"^\| {name}: .*$", text, re.M)
        assert row is not None, name
        cells = row.group(0).strip("|").split("|")
        flash, ram, stack = (int(c) for c in cells[1:4])
        low, median, high = (float(c) for c in cells[4].split(" / "))
        assert flash > 0 and ram >= 0 and stack > 0 and 0 < low <= median <= high
        assert re.search(rf"^  {name} +{flash} +{ram} +{stack} ", out, re.M)


def test_without_the_toolchain_the_report_says_so(capsys, monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(toolchain, "SIMAVR_INCLUDE_DIRS", (str(tmp_path),))
    toolchain.find_toolchain.cache_clear()
    try:
        assert main(SMALL) == 0
        out = capsys.readouterr().out
        assert re.search(r"^AVR build: not measured: the AVR toolchain is missing .*: apt-get install", out, re.M)
        assert main([*SMALL, "--doc", str(tmp_path / "page.md")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("twin-firmware-report: --doc needs the AVR build: ") and err.count("\n") == 1
    finally:
        toolchain.find_toolchain.cache_clear()
