"""Every project file the README, docs/ and the code's docstrings name exists: a test or module that
moved takes its mentions with it."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("firmware_port", "twin", "protocol", "tools", "tests")
# A path into one of the packages, as prose names it (not part of a longer path such as heater-twin/...).
NAMED_PATH = re.compile(r"(?<![\w/.-])(?:" + "|".join(PACKAGES) + r")/[\w/]+\.(?:py|md|txt|c)\b")


def _texts() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for package in PACKAGES:
        files += sorted((ROOT / package).rglob("*.py"))
    return files


def named_paths(text: str) -> set[str]:
    return set(NAMED_PATH.findall(text))


def test_the_pattern_finds_paths_in_prose():
    text = "see tests/twin/test_engine.py, (tools/bench.py) and heater-twin/tools/x.py or twin-out/a.py"
    assert named_paths(text) == {"tests/twin/test_engine.py", "tools/bench.py"}


def test_every_named_project_file_exists():
    missing = sorted({(str(f.relative_to(ROOT)), p) for f in _texts() for p in named_paths(f.read_text())
                      if not (ROOT / p).exists()})
    assert missing == []
