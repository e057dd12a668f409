"""Write PID gains into printer.cfg's SAVE_CONFIG block, as PID_CALIBRATE followed by SAVE_CONFIG does.

Klipper's own rules (klippy/configfile.py), followed here with code of our own: the block starts at
AUTOSAVE_HEADER, every line after it is ``#*# `` and a config line; the saved options replace the
block's old values of that section and keep the rest; the same options in the file's regular part
are commented out with ``#`` (their continuation lines too); an option that an included file sets
is a conflict (SAVE_CONFIG refuses it); the old file is kept as printer-YYYYMMDD_HHMMSS.cfg and the
new one is swapped in by a rename. PID_CALIBRATE saves ``control: pid`` and the gains with 3 decimals.
"""

from __future__ import annotations

import configparser
import glob
import io
import os
import re
import time
from pathlib import Path

AUTOSAVE_HEADER = """
#*# <---------------------- SAVE_CONFIG ---------------------->
#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.
#*#
"""
PREFIX = "#*# "
COMMENT = re.compile(r"[#;].*$")
OPTION_NAME = re.compile(r"[^A-Za-z0-9_].*$")


class AutosaveError(ValueError):
    """The config cannot take the block: unreadable, or an included file sets one of the options."""


def pid_options(kp: float, ki: float, kd: float) -> dict[str, str]:
    """The options PID_CALIBRATE saves: control and the three gains, as it formats them."""
    return {"control": "pid", "pid_kp": f"{kp:.3f}", "pid_ki": f"{ki:.3f}", "pid_kd": f"{kd:.3f}"}


def split_autosave(text: str) -> tuple[str, str]:
    """(the regular part, the block's config text without its prefixes); the block is '' if there is none."""
    regular, found, block = text.partition(AUTOSAVE_HEADER)
    if not found:
        return text, ""
    lines = [line[len(PREFIX):] if line.startswith(PREFIX) else "" for line in block.strip().split("\n")]
    if any(line and not line.startswith("#*#") for line in block.strip().split("\n")):
        raise AutosaveError("the SAVE_CONFIG block was edited by hand (a line without '#*#'): not touching it")
    return regular, "\n".join(lines)


def options_by_line(text: str):
    """(line number, section, option) of each option line of a config text, continuation lines as option None."""
    section = None
    for number, line in enumerate(text.split("\n")):
        pruned = COMMENT.sub("", line).rstrip()
        if not pruned:
            continue
        if pruned[0].isspace():
            yield number, section, None
        elif pruned.startswith("["):
            section = pruned[1:-1].strip()
        else:
            yield number, section, OPTION_NAME.sub("", pruned).lower()


def comment_out(regular: str, section: str, options: set[str]) -> str:
    """The regular part with ``section``'s ``options`` (and their continuation lines) commented out."""
    lines = regular.split("\n")
    in_duplicate = False
    for number, at, option in options_by_line(regular):
        if option is not None:
            in_duplicate = at == section and option in options
        if in_duplicate:
            lines[number] = "#" + lines[number]
    return "\n".join(lines)


def included_files(config_path: Path, regular: str) -> list[Path]:
    """Every file the regular part includes (``[include GLOB]``, relative to its folder), recursively."""
    found: list[Path] = []
    for spec in re.findall(r"^\[include\s+([^\]]+)\]", regular, flags=re.MULTILINE):
        for name in sorted(glob.glob(str(config_path.parent / spec.strip()))):
            path = Path(name)
            if path not in found:
                found += [path, *included_files(path, path.read_text())]
    return found


def check_includes(config_path: Path, regular: str, section: str, options: set[str]) -> None:
    """AutosaveError if an included file sets one of ``section``'s ``options`` (SAVE_CONFIG's rule)."""
    for path in included_files(config_path, regular):
        for _, at, option in options_by_line(path.read_text()):
            if at == section and option in options:
                raise AutosaveError(f"[{section}] {option} is set in the included {path.name}: SAVE_CONFIG "
                                    "cannot override it; move it to printer.cfg")


def merged_block(block: str, section: str, options: dict[str, str]) -> str:
    """The block's config with ``section``'s ``options`` set, as ``#*# `` lines under the header."""
    parser = configparser.RawConfigParser(strict=False, inline_comment_prefixes=("#", ";"))
    parser.read_file(io.StringIO(block))
    if not parser.has_section(section):
        parser.add_section(section)
    for option, value in options.items():
        parser.set(section, option, value)
    out = io.StringIO()
    parser.write(out)
    lines = [(PREFIX + line).strip() for line in out.getvalue().strip().split("\n")]
    return "\n" + AUTOSAVE_HEADER.rstrip() + "\n" + "\n".join(lines) + "\n"


def save_options(config_path: Path, section: str, options: dict[str, str]) -> Path:
    """Write ``options`` into ``section`` of the file's SAVE_CONFIG block; the backup's path."""
    text = config_path.read_text().replace("\r\n", "\n")
    regular, block = split_autosave(text)
    check_includes(config_path, regular, section, set(options))
    data = comment_out(regular, section, set(options)).rstrip() + merged_block(block, section, options)
    stamp = time.strftime("-%Y%m%d_%H%M%S")
    backup = config_path.with_name(config_path.stem + stamp + config_path.suffix)
    temp = config_path.with_name(config_path.stem + "_autosave" + config_path.suffix)
    temp.write_text(data)
    os.rename(config_path, backup)
    os.rename(temp, config_path)
    return backup
