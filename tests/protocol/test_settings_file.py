"""The settings file (M500's EEPROM) as protocol/settings.py keeps it: written whole or not at all,
never through a link or over a file M500 did not write, read with a bound, and a damaged file
loaded as Marlin loads an EEPROM whose CRC does not match."""

from __future__ import annotations

import json
import os
import re
import subprocess

import pytest

from firmware_port.marlin.pid import PidGains
from protocol.build import build_printer
from protocol.settings import MAX_FILE_BYTES, TEMP_SUFFIX, Settings, crc16
from tests.helpers.serial_host import CLI, ROOT, START_TIMEOUT_S

STORED = re.compile(r"echo:Settings Stored \((\d+) bytes; crc (\d+)\)")
CRC_MISMATCH = re.compile(r"Error:EEPROM CRC mismatch - \(stored\) (\d+) != (\d+) \(calculated\)!")


def _send(printer, *lines: str) -> list[str]:
    for line in lines:
        printer.receive(line.encode() + b"\n")
    printer.run_until_idle()
    return printer.take_output().decode().splitlines()


def _banner(printer) -> list[str]:
    return printer.take_output().decode().splitlines()


@pytest.fixture
def eeprom(tmp_path):
    return tmp_path / "eeprom.json"


def _stored_printer(eeprom, gains="M301 P15 I1.5 D60"):
    """A printer that stored ``gains`` with M500 (banner read)."""
    printer = build_printer(settings=str(eeprom))
    _banner(printer)
    assert _send(printer, gains, "M500")[-1] == "ok"
    return printer


def test_m500_writes_the_file_whole_and_reports_what_its_crc_covers(eeprom):
    printer = _stored_printer(eeprom)
    lines = _send(printer, "M500")
    size, crc = map(int, STORED.fullmatch(lines[0]).groups())
    doc = json.loads(eeprom.read_bytes())
    assert doc.pop("crc") == crc
    payload = json.dumps(doc, indent=1, sort_keys=True).encode()  # the image without its crc
    assert (len(payload), crc16(payload)) == (size, crc)
    assert sorted(os.listdir(eeprom.parent)) == ["eeprom.json"]  # M500's new file was renamed, none left
    again = _banner(build_printer(settings=str(eeprom)))
    assert f"echo:V87 stored settings retrieved ({size} bytes; crc {crc})" in again
    assert "echo:  M301 P15.00 I1.50 D60.00" in again


def test_a_damaged_file_loads_the_defaults_with_marlins_crc_line(eeprom):
    _stored_printer(eeprom)
    eeprom.write_text(eeprom.read_text().replace('"kp": 15.0', '"kp": 51.0'))  # a flipped digit, or a hand edit
    banner = _banner(printer := build_printer(settings=str(eeprom)))
    k = next(i for i, line in enumerate(banner) if CRC_MISMATCH.fullmatch(line))
    stored, calculated = map(int, CRC_MISMATCH.fullmatch(banner[k]).groups())
    assert stored == json.loads(eeprom.read_bytes())["crc"] and stored != calculated
    assert banner[k + 1] == "echo:Hardcoded Default Settings Loaded"
    assert "echo:  M301 P19.96 I2.06 D48.23" in banner  # the build's own gains, not 51
    _send(printer, "M500")  # as on the board, the next M500 stores over it
    assert "stored settings retrieved" in _banner(build_printer(settings=str(eeprom)))[5]


def test_a_damaged_file_is_kept_when_asked(eeprom):
    _stored_printer(eeprom)
    damaged = eeprom.read_text().replace('"kp": 15.0', '"kp": 51.0')
    eeprom.write_text(damaged)
    with pytest.raises(ValueError, match=r"does not load \(CRC mismatch, stored \d+, calculated \d+\); kept"):
        build_printer(settings=str(eeprom), keep_corrupt_settings=True)
    assert eeprom.read_text() == damaged


def test_an_older_layout_is_a_version_mismatch_naming_the_version(eeprom):
    _stored_printer(eeprom)
    eeprom.write_text(eeprom.read_text().replace('"V87"', '"V86"'))
    banner = _banner(build_printer(settings=str(eeprom)))
    assert "echo:EEPROM version mismatch (EEPROM=V86 Marlin=V87)" in banner


def test_a_file_stored_before_the_crc_loads_as_it_is(eeprom):
    """Files M500 wrote before it stored a CRC: nothing the user stored is lost on upgrade."""
    eeprom.write_bytes(Settings(hotend=PidGains(17.5, 1.25, 60.0)).payload())
    assert "echo:  M301 P17.50 I1.25 D60.00" in _banner(build_printer(settings=str(eeprom)))


@pytest.mark.parametrize("planted", ["link to a file", "dangling link", "foreign file"])
def test_m500_refuses_what_was_planted_at_the_path_after_start(eeprom, tmp_path, planted, caplog):
    """The classic /tmp attack: the settings path swapped for a link to a file of the user's, or for
    a link to where a file would be created, or a file that is not a settings file. M500 answers
    Marlin's write error (then its report and ok, as Marlin 2.1 ignores write_data's result) and
    leaves everything as it found it; the log says why."""
    printer = _stored_printer(eeprom)
    victim = tmp_path / "victim.txt"
    if planted == "link to a file":
        victim.write_text("the user's own file\n")
    if planted == "foreign file":
        eeprom.unlink()
        eeprom.write_text("the user's own file\n")
    else:
        eeprom.unlink()
        eeprom.symlink_to(victim)
    lines = _send(printer, "M301 P40", "M500", "M105")
    assert lines[1:3] == ["echo:Error writing to EEPROM!", lines[2]] and STORED.fullmatch(lines[2])
    assert lines[3] == "ok" and lines[4].startswith("ok T:")
    assert eeprom.is_symlink() == (planted != "foreign file")
    if planted == "dangling link":
        assert not victim.exists()
    else:
        assert (eeprom if planted == "foreign file" else victim).read_text() == "the user's own file\n"
    assert "M500 not written" in caplog.text


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o664])
def test_m500_keeps_the_settings_files_permission_bits(eeprom, mode):
    """The new file renamed over the old one has the old one's mode, not the umask's: a file the user made
    private stays private."""
    printer = _stored_printer(eeprom)
    eeprom.chmod(mode)
    old_umask = os.umask(0o002)  # a new file would be 0o664 under it
    try:
        assert _send(printer, "M301 P40", "M500")[-1] == "ok"
    finally:
        os.umask(old_umask)
    assert Settings.from_bytes(eeprom.read_bytes()).hotend.kp == 40
    assert eeprom.stat().st_mode & 0o7777 == mode


def test_a_read_only_settings_file_is_left_alone(eeprom, monkeypatch):
    printer = _stored_printer(eeprom)
    kept = eeprom.read_bytes()
    eeprom.chmod(0o444)
    if os.geteuid() == 0:  # root may write anything: answer as access() answers its owner
        access = os.access
        monkeypatch.setattr(os, "access", lambda path, mode, **kw: not mode & os.W_OK and access(path, mode, **kw))
    assert _send(printer, "M301 P40", "M500")[1] == "echo:Error writing to EEPROM!"
    assert eeprom.read_bytes() == kept


def test_a_link_planted_after_start_is_not_read_either(eeprom, tmp_path, caplog):
    """A reset (a new host) reads the EEPROM again: a link to /dev/zero there reads as a blank EEPROM."""
    printer = _stored_printer(eeprom)
    eeprom.unlink()
    eeprom.symlink_to("/dev/zero")
    printer.reset()
    banner = _banner(printer)
    assert "echo:EEPROM version mismatch (EEPROM=? Marlin=V87)" in banner
    assert "is a symbolic link" in caplog.text


@pytest.mark.parametrize("what, reason", [
    ("link", "is a symbolic link"), ("/dev/zero", "is not a regular file"), ("fifo", "is not a regular file"),
    ("folder", "is not a regular file"), ("huge", f"is larger than {MAX_FILE_BYTES} bytes"),
])
def test_start_refuses_what_it_must_not_read_whole(tmp_path, what, reason):
    """One line, at once: a link (even to a settings file), a device, a FIFO (opened without
    blocking), a folder, a file larger than any settings image (a sparse 4 GB file, read no further
    than MAX_FILE_BYTES + 1)."""
    path = tmp_path / "eeprom.json"
    if what == "link":
        (tmp_path / "real.json").write_bytes(Settings().to_bytes())
        path.symlink_to(tmp_path / "real.json")
    elif what == "/dev/zero":
        path = "/dev/zero"
    elif what == "fifo":
        os.mkfifo(path)
    elif what == "folder":
        path.mkdir()
    else:
        with open(path, "wb") as file:
            file.truncate(4 << 30)
    with pytest.raises(ValueError, match=f"^settings file {path}: {reason}"):
        build_printer(settings=str(path))


def test_files_a_crash_left_before_their_rename_are_removed_at_start(eeprom):
    _stored_printer(eeprom)
    leftover = eeprom.parent / f".eeprom.json.0123456789ab{TEMP_SUFFIX}"
    leftover.write_bytes(b'{"bed_pid": {')
    others = [eeprom.parent / name for name in (".eeprom.json.swp", "notes.txt", f".other.json.0123456789ab{TEMP_SUFFIX}")]
    for other in others:
        other.write_text("keep me\n")
    build_printer(settings=str(eeprom))
    assert not leftover.exists() and all(other.read_text() == "keep me\n" for other in others)


@pytest.mark.slow
def test_twin_serial_keeps_a_damaged_file_when_asked(eeprom):
    _stored_printer(eeprom)
    damaged = eeprom.read_text().replace('"kp": 15.0', '"kp": 51.0')
    eeprom.write_text(damaged)
    proc = subprocess.run([*CLI, "--settings", str(eeprom), "--keep-corrupt-settings"], capture_output=True,
                          text=True, cwd=ROOT, timeout=START_TIMEOUT_S)
    assert proc.returncode == 2 and proc.stdout == ""
    assert re.fullmatch(rf"twin-serial: error: settings file {eeprom}: does not load \(CRC mismatch, stored \d+, "
                        r"calculated \d+\); kept as it is, as asked\n", proc.stderr)
    assert eeprom.read_text() == damaged
