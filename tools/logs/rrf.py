"""RepRapFirmware's heater model results ('; Heater n model: ...'): recognised, so that the error
says what the file is, but not read (no reader here turns them into a series or a relay result)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import NoReturn

from tools.logs.lines import LogError
from tools.logs.registry import Head, Reader

MODEL_RE = re.compile(r"^; Heater \d+ model:")


def refuse_rrf(path: str | Path) -> NoReturn:
    """LogError at the first model line."""
    head = Head.of(path)
    line_no = next(no for (no, _), text in zip(head.lines, head.texts) if MODEL_RE.match(text))
    raise LogError(path, line_no, "RepRapFirmware heater model results ('; Heater n model: ...'): no reader here")


READER = Reader("RepRapFirmware heater models", lambda head: any(MODEL_RE.match(text) for text in head.texts),
                refuse_rrf)
