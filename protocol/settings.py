"""The printer's EEPROM: PID gains (and MPC's model on an MPC build) kept in a file the user
names (M500/M501/M502/M503).

The file is JSON (readable, diffable) with a CRC16 over the rest of it, as Marlin keeps one over its
EEPROM image: a file damaged (or edited by hand) since M500 wrote it loads the defaults with
Marlin's CRC mismatch line. The byte count and CRC that Marlin prints are those of the bytes the
CRC covers. A file without ``crc`` (written before the twin stored one) loads as it is.

Nothing stored is lost and nothing else is overwritten: M500 writes a new file beside the old one,
flushes it to disk and renames it over the old one, so a crash at any instant leaves the old
settings or the new ones, never a mix; and it does so only where the path holds nothing or a
settings file, looked at again at every M500 through the folder opened at start, without
following links. A symbolic link (planted or dangling), a device, or a file M500 did not write is
refused. Reads are bounded (MAX_FILE_BYTES): a link to /dev/zero is refused, never read.
"""

from __future__ import annotations

import errno
import json
import os
import re
import secrets
import stat
import weakref
from dataclasses import dataclass
from pathlib import Path

from firmware_port.marlin.mpc import MpcConstants
from firmware_port.marlin.pid import BED_GAINS, HOTEND_GAINS, PidGains
from twin.limits import UserError

EEPROM_VERSION = "V87"  # Marlin 2.1's settings version string
MAX_FILE_BYTES = 4096  # an image is about 330 bytes (480 with MPC): a larger file is not one, and is not read on
TEMP_SUFFIX = ".m500-tmp"  # M500's new file until it is renamed over the old one (".NAME.<12 hex>.m500-tmp")
_NO_FOLLOW = os.O_NOFOLLOW | os.O_CLOEXEC


def crc16(data: bytes) -> int:
    """Marlin's crc16 (CCITT polynomial 0x1021, starting at 0), as settings.cpp uses it."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


class ImageError(ValueError):
    """A stored image that does not load."""


class VersionMismatch(ImageError):
    """Not this version's layout; ``shown`` is what Marlin prints for the stored version ('?' unless it
    is a three-character version string, as settings.cpp's ``stored_ver[3] != '\\0'`` test)."""

    def __init__(self, stored: object):
        self.shown = stored if isinstance(stored, str) and len(stored) == 3 else "?"
        super().__init__(f"version {self.shown}, expected {EEPROM_VERSION}")


class CrcMismatch(ImageError):
    """The stored CRC is not that of the bytes it covers: the file changed since M500 wrote it."""

    def __init__(self, stored: int, calculated: int):
        self.stored, self.calculated = stored, calculated
        super().__init__(f"CRC mismatch, stored {stored}, calculated {calculated}")


def _dumps(doc: dict) -> bytes:
    return json.dumps(doc, indent=1, sort_keys=True).encode()


@dataclass
class Settings:
    """What M500 stores: the hotend and bed PID gains in user units, and MPC_t on an MPC build."""

    hotend: PidGains = HOTEND_GAINS
    bed: PidGains = BED_GAINS
    hotend_mpc: MpcConstants | None = None  # None: no MPC stored, the build's own constants apply

    def _doc(self) -> dict:
        doc = {"version": EEPROM_VERSION, "hotend_pid": vars(self.hotend), "bed_pid": vars(self.bed)}
        if self.hotend_mpc is not None:
            doc["hotend_mpc"] = vars(self.hotend_mpc)
        return doc

    def payload(self) -> bytes:
        """The bytes the CRC covers (the image without its crc): what M500 and M501 count."""
        return _dumps(self._doc())

    def to_bytes(self) -> bytes:
        """The file M500 writes."""
        return _dumps({**self._doc(), "crc": crc16(self.payload())})

    @classmethod
    def from_bytes(cls, data: bytes) -> Settings:
        """Parse a stored image; ImageError says what is wrong with it."""
        return load_image(data)[0]


def _json_object(data: bytes) -> dict | None:
    try:
        doc = json.loads(data.decode())
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def load_image(data: bytes) -> tuple[Settings, bytes]:
    """The settings in a stored image and the bytes its CRC covers. As Marlin's settings.load()
    checks, the version first (VersionMismatch, also for a layout that is not this version's), then
    the CRC (CrcMismatch)."""
    doc = _json_object(data)
    if doc is None or doc.get("version") != EEPROM_VERSION:
        raise VersionMismatch(None if doc is None else doc.get("version"))
    stored = doc.pop("crc", None)
    payload = _dumps(doc)
    if stored is not None and stored != crc16(payload):
        raise CrcMismatch(stored if isinstance(stored, int) else 0, crc16(payload))
    try:
        mpc = doc.get("hotend_mpc")
        settings = Settings(PidGains(**doc["hotend_pid"]), PidGains(**doc["bed_pid"]),
                            None if mpc is None else MpcConstants(**mpc))
    except (KeyError, TypeError, ValueError):
        raise VersionMismatch(None) from None
    return settings, payload


def is_settings_image(data: bytes) -> bool:
    """The bytes are a JSON object of the shape M500 writes (whether or not it loads: M501 then
    reports a version or CRC mismatch, as Marlin does for an old or damaged EEPROM)."""
    doc = _json_object(data)
    return doc is not None and {"version", "hotend_pid", "bed_pid"} <= doc.keys()


class SettingsRefused(OSError):
    """What the settings path holds now is not M500's to read or replace (a link, a device, a file
    M500 did not write); the message names the file and the reason."""


class Eeprom:
    """A settings file; without a path the EEPROM is lost when the program ends.

    The file's folder is opened once, here, and every read and write goes through it by name
    without following a link, so what M500 replaces is always what it has just looked at there.
    ``keep_corrupt``: a settings file that does not load is refused like a foreign one (M500 does
    not replace it) instead of giving way to the defaults as on the board.
    """

    def __init__(self, path: str | Path | None = None, *, keep_corrupt: bool = False):
        self.path = Path(path) if path is not None else None
        self.keep_corrupt = keep_corrupt
        self._memory: bytes | None = None
        self._name = self.path.name if self.path is not None else ""
        self._folder_fd = -1
        if self.path is not None:
            self._folder_fd = os.open(self.path.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
            weakref.finalize(self, os.close, self._folder_fd)

    def __repr__(self) -> str:
        return f"Eeprom({self.path or 'in memory'})"

    @classmethod
    def open(cls, path: str | Path, *, keep_corrupt: bool = False) -> Eeprom:
        """The settings file ``path``: new, empty, or one M500 wrote, in a folder where M500 can
        write. UserError (one line naming the file) otherwise; M500's files left by a crash are
        removed."""
        path = Path(path)
        try:
            eeprom = cls(path, keep_corrupt=keep_corrupt)
        except FileNotFoundError:
            raise UserError(f"settings file {path}: its directory does not exist") from None
        except OSError as exc:
            raise UserError(f"settings file {path}: cannot open its directory ({exc.strerror})") from None
        try:
            problem = eeprom._refusal()
        except OSError as exc:
            raise UserError(f"settings file {path}: cannot read it ({exc.strerror})") from None
        if problem:
            raise UserError(problem)
        eeprom._remove_leftovers()
        eeprom._check_writable()
        return eeprom

    def read(self) -> bytes | None:
        """The stored image, None when there is none. SettingsRefused if the path holds a link, a
        device or more than MAX_FILE_BYTES now; OSError if it cannot be read."""
        if self.path is None:
            return self._memory
        return self._read_file()

    def write(self, data: bytes) -> None:
        """Store the image: a new file beside the old one, on disk, then renamed over it (see the
        module's docstring). SettingsRefused if the path holds what M500 must not replace; OSError
        if the file cannot be written (M500 answers as Marlin does)."""
        if self.path is None:
            self._memory = data
            return
        problem = self._refusal()
        if problem:
            raise SettingsRefused(problem)
        mode = self._mode()
        name, fd = self._new_file()
        try:
            try:
                if mode is not None:
                    os.fchmod(fd, mode)  # the file keeps its permission bits (a new one gets the umask's)
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(name, self._name, src_dir_fd=self._folder_fd, dst_dir_fd=self._folder_fd)
        except BaseException:
            _remove(name, self._folder_fd)
            raise
        os.fsync(self._folder_fd)  # the rename itself reaches the disk

    # -- the file, through the folder -----------------------------------------------------------
    def _read_file(self) -> bytes | None:
        try:  # O_NONBLOCK: a FIFO at the path must not block the open
            fd = os.open(self._name, os.O_RDONLY | os.O_NONBLOCK | _NO_FOLLOW, dir_fd=self._folder_fd)
        except FileNotFoundError:
            return None
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise SettingsRefused(f"settings file {self.path}: is a symbolic link; give the file itself "
                                      "(M500 never writes through a link)") from None
            raise
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise SettingsRefused(f"settings file {self.path}: is not a regular file")
            data = b""
            while len(data) <= MAX_FILE_BYTES:
                chunk = os.read(fd, MAX_FILE_BYTES + 1 - len(data))
                if not chunk:
                    break
                data += chunk
        finally:
            os.close(fd)
        if len(data) > MAX_FILE_BYTES:
            raise SettingsRefused(f"settings file {self.path}: is larger than {MAX_FILE_BYTES} bytes, so not a "
                                  "heater-twin settings file")
        return data

    def _refusal(self) -> str | None:
        """Why M500 must not replace what the path holds now (None: nothing, an empty file, or a
        settings file it may replace)."""
        try:
            data = self._read_file()
        except SettingsRefused as exc:
            return str(exc)
        if data is None:
            return None
        if data and not is_settings_image(data):
            return (f"settings file {self.path}: not a heater-twin settings file (M500 writes JSON with version, "
                    "hotend_pid and bed_pid); refusing to overwrite it")
        if self.keep_corrupt:
            try:
                load_image(data)
            except ImageError as exc:
                return f"settings file {self.path}: does not load ({exc}); kept as it is, as asked"
        if not os.access(self._name, os.W_OK, dir_fd=self._folder_fd):
            return f"settings file {self.path}: is read-only; M500 leaves it as it is"
        return None

    def _mode(self) -> int | None:
        """The permission bits of the settings file there now; None when there is none."""
        try:
            return stat.S_IMODE(os.stat(self._name, dir_fd=self._folder_fd, follow_symlinks=False).st_mode)
        except FileNotFoundError:
            return None

    def _new_file(self) -> tuple[str, int]:
        """A file of M500's own beside the settings file (O_EXCL: nobody else's), named so that a
        later start can tell it from anything else there."""
        while True:
            name = f".{self._name}.{secrets.token_hex(6)}{TEMP_SUFFIX}"
            try:
                return name, os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NO_FOLLOW, 0o666,
                                     dir_fd=self._folder_fd)
            except FileExistsError:
                continue

    def _remove_leftovers(self) -> None:
        """M500's new files that a crash left before their rename (the settings file itself is whole)."""
        mine = re.compile(rf"\.{re.escape(self._name)}\.[0-9a-f]{{12}}{re.escape(TEMP_SUFFIX)}")
        for name in os.listdir(self._folder_fd):
            if mine.fullmatch(name):
                _remove(name, self._folder_fd)

    def _check_writable(self) -> None:
        """At start, so M500 does not fail later: M500 can create its file in the folder. Nothing is
        changed: the probe file is removed at once. ValueError says why not."""
        try:
            name, fd = self._new_file()
            os.close(fd)
            _remove(name, self._folder_fd)
        except OSError as exc:
            raise UserError(f"settings file {self.path}: cannot be written ({exc.strerror or exc})") from None


def _remove(name: str, folder_fd: int) -> None:
    try:
        os.unlink(name, dir_fd=folder_fd)
    except FileNotFoundError:
        pass
