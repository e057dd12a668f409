"""Where the captured hardware logs are: $HEATER_TWIN_HARDWARE_LOGS, else the shared captures
beside the repository."""

from __future__ import annotations

import os
from pathlib import Path

LOGS_ENV = "HEATER_TWIN_HARDWARE_LOGS"
DEFAULT_LOGS = Path(__file__).resolve().parents[3] / "shared" / "hardware_logs"  # <repo>/tools/logs/ -> <repo>/..


def hardware_logs_dir() -> Path:
    """The captured hardware logs: $HEATER_TWIN_HARDWARE_LOGS, else <repo>/../shared/hardware_logs."""
    path = Path(os.environ.get(LOGS_ENV) or DEFAULT_LOGS)
    if not path.is_dir():
        raise FileNotFoundError(f"hardware logs not found at {path}: set {LOGS_ENV} to the hardware_logs folder")
    return path
