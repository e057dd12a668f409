"""The printer's EEPROM: PID gains (and MPC's model on an MPC build) kept in a file the user
names (M500/M501/M502/M503).

The file is JSON (readable, diffable); what Marlin prints about it (byte count, CRC16) is
computed over the stored bytes as Marlin computes it over its EEPROM image.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

from firmware_port.marlin.mpc import MpcConstants
from firmware_port.marlin.pid import BED_GAINS, HOTEND_GAINS, PidGains

EEPROM_VERSION = "V87"  # Marlin 2.1's settings version string


def crc16(data: bytes) -> int:
    """Marlin's crc16 (CCITT polynomial 0x1021, starting at 0), as settings.cpp uses it."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


@dataclass
class Settings:
    """What M500 stores: the hotend and bed PID gains in user units, and MPC_t on an MPC build."""

    hotend: PidGains = HOTEND_GAINS
    bed: PidGains = BED_GAINS
    hotend_mpc: MpcConstants | None = None  # None: no MPC stored, the build's own constants apply

    def to_bytes(self) -> bytes:
        data = {"version": EEPROM_VERSION, "hotend_pid": vars(self.hotend), "bed_pid": vars(self.bed)}
        if self.hotend_mpc is not None:
            data["hotend_mpc"] = vars(self.hotend_mpc)
        return json.dumps(data, indent=1, sort_keys=True).encode()

    @classmethod
    def from_bytes(cls, data: bytes) -> Settings:
        """Parse a stored image; ValueError says what is wrong with it."""
        try:
            doc = json.loads(data.decode())
            if doc.get("version") != EEPROM_VERSION:
                raise ValueError(f"version {doc.get('version')!r}, expected {EEPROM_VERSION}")
            mpc = doc.get("hotend_mpc")
            return cls(PidGains(**doc["hotend_pid"]), PidGains(**doc["bed_pid"]),
                       None if mpc is None else MpcConstants(**mpc))
        except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"unreadable settings: {exc}") from exc


def is_settings_image(data: bytes) -> bool:
    """The bytes are a JSON object of the shape M500 writes (any version: M501 then reports a
    version mismatch, as Marlin does for an old EEPROM layout)."""
    try:
        doc = json.loads(data.decode())
    except (UnicodeDecodeError, json.JSONDecodeError):
        return False
    return isinstance(doc, dict) and {"version", "hotend_pid", "bed_pid"} <= doc.keys()


class Eeprom:
    """A settings file; without a path the EEPROM is lost when the program ends."""

    def __init__(self, path: str | Path | None = None):
        self.path = Path(path) if path is not None else None
        self._memory: bytes | None = None

    @classmethod
    def open(cls, path: str | Path) -> Eeprom:
        """The settings file ``path``: new, empty, or one M500 wrote. ValueError otherwise, so
        M500 never overwrites a file the twin did not write."""
        path = Path(path)
        if not path.resolve().parent.is_dir():
            raise ValueError(f"settings file {path}: its directory does not exist")
        if path.is_dir():
            raise ValueError(f"settings file {path}: is a directory")
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            data = b""
        except OSError as exc:
            raise ValueError(f"settings file {path}: cannot read it ({exc.strerror})") from None
        if data and not is_settings_image(data):
            raise ValueError(f"settings file {path}: not a heater-twin settings file (M500 writes JSON with "
                             "version, hotend_pid and bed_pid); refusing to overwrite it")
        _check_writable(path)
        return cls(path)

    def read(self) -> bytes | None:
        if self.path is None:
            return self._memory
        try:
            return self.path.read_bytes()
        except FileNotFoundError:
            return None

    def write(self, data: bytes) -> None:
        """Store the image; OSError if the file cannot be written (M500 answers as Marlin does)."""
        if self.path is None:
            self._memory = data
        else:
            self.path.write_bytes(data)


def _check_writable(path: Path) -> None:
    """At start, so M500 does not fail later: the file opens for writing, or (a new file) a file can
    be created beside it. Nothing is changed: an existing file is opened without truncating, a probe
    file is removed at once. ValueError says why not."""
    try:
        if path.exists():
            with open(path, "r+b"):
                pass
        else:
            with tempfile.NamedTemporaryFile(dir=path.resolve().parent, prefix=".heater-twin-probe-"):
                pass
    except OSError as exc:
        raise ValueError(f"settings file {path}: cannot be written ({exc.strerror or exc})") from None
