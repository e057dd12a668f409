"""The user's cache folder for what heater-twin builds (AVR images, compiled lane laws):
``$XDG_CACHE_HOME/heater-twin``, else ``~/.cache/heater-twin``."""

from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/heater-twin``, else ``~/.cache/heater-twin`` (the XDG base directory rule)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "heater-twin"
