"""What twin-serial's settings file survives, as a process: a crash (SIGKILL) at any instant of a
stream of M500s, and a settings path that is a link to a device.

The crash trials fork twin-serial from a forkserver that has imported it once (each trial is then
a fresh process in milliseconds, not an interpreter start); each start after a kill is the
restart whose banner must show the settings last acknowledged, or the ones being stored when it
died."""

from __future__ import annotations

import multiprocessing
import os
import random
import re
import resource
import subprocess
import threading
import time

import pytest
import serial

from protocol.settings import Settings
from tests.helpers.serial_host import CLI, READ_TIMEOUT_S, ROOT, START_TIMEOUT_S, expect
from tools.cli import serial as serial_cli

TRIALS = 40
SEED = 500
KILL_WITHIN_S = 0.3  # after the stream starts: a few dozen M500s at most
GAINS = re.compile(r"echo:  M301 P(\d+\.\d\d) ")
P_BASE, P_STEP = 100.0, 0.01  # the n-th P sent: 100.00, 100.01, ... (unique, within the firmware's |P| <= 1000)


def _p(n: int) -> str:
    return f"{P_BASE + n * P_STEP:.2f}"


def _n(p: float) -> int:
    return round((p - P_BASE) / P_STEP)
DATA_LIMIT_BYTES = 768 << 20  # twin-serial's imports need about 300 MB of data segment and mappings (170 MB resident)


class _Gone(Exception):
    """The printer's end of the port closed: the process died."""


def _start(context, link, eeprom):
    """twin-serial on a pty (host-driven clock) with ``eeprom``; its port opened once ``link`` is there."""
    if link.is_symlink():
        link.unlink()  # a killed twin-serial leaves it: wait for the new one's
    proc = context.Process(target=serial_cli.main, args=(["--link", str(link), "--settings", str(eeprom),
                                                          "--idle-speed", "0"],))
    proc.start()
    deadline = time.monotonic() + START_TIMEOUT_S
    while not link.is_symlink():
        assert proc.is_alive() and time.monotonic() < deadline, "twin-serial did not make its port"
        time.sleep(0.01)
    return proc, serial.Serial(str(link), 115200, timeout=READ_TIMEOUT_S)


def _line(port) -> str:
    try:
        data = port.readline()
    except (serial.SerialException, OSError):
        raise _Gone from None
    if not data:
        raise _Gone  # nothing within the timeout: the printer is gone (a live one answers M500 at once)
    return data.decode("latin-1").rstrip("\n")


def _stream_until_killed(port, first: int) -> int | None:
    """``M301 P<_p(n)>`` and ``M500`` for n = first, first + 1, ...; the last n whose M500 was acknowledged."""
    acked = None
    try:
        for value in range(first, first + 80_000):
            port.write(f"M301 P{_p(value)}\nM500\n".encode())
            while not _line(port).startswith("echo:Settings Stored"):
                pass
            while _line(port) != "ok":
                pass
            acked = value
    except (_Gone, serial.SerialException, OSError):
        pass
    return acked


def _stored_gain(banner: list[str]) -> int | None:
    """The n of the hotend P the banner loaded from the file, None for the defaults of a missing file."""
    if "echo:Hardcoded Default Settings Loaded" in banner:
        assert not any("mismatch" in line for line in banner), banner  # never a damaged file
        return None
    assert any(line.startswith("echo:V87 stored settings retrieved (") for line in banner), banner
    return _n(float(next(GAINS.match(line) for line in banner if GAINS.match(line)).group(1)))


@pytest.mark.slow
def test_a_crash_at_any_instant_of_m500_keeps_the_old_settings_or_the_new(tmp_path):
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["tools.cli.serial"])
    rng = random.Random(SEED)
    folder = tmp_path / "settings"
    folder.mkdir()
    eeprom, link = folder / "eeprom.json", tmp_path / "printer"
    allowed: set[int | None] = {None}  # no file yet
    acked: int | None = None
    value = 0  # the n of the next P to send: each is sent once in the whole test
    for trial in range(TRIALS + 1):
        proc, port = _start(context, link, eeprom)
        try:
            stored = _stored_gain(expect(port, "M304"))  # the banner's last line
            assert stored in allowed, f"trial {trial}: the file holds n={stored}, expected one of {allowed}"
            assert sorted(os.listdir(folder)) == ([] if stored is None else ["eeprom.json"])  # no leftovers
            if stored is not None:
                assert _n(Settings.from_bytes(eeprom.read_bytes()).hotend.kp) == stored
            if trial == TRIALS:
                proc.terminate()
                return
            killer = threading.Timer(rng.uniform(0.0, KILL_WITHIN_S), proc.kill)
            killer.start()
            acked = _stream_until_killed(port, value)
            killer.join()
            proc.join(START_TIMEOUT_S)
        finally:
            port.close()
            if proc.is_alive():
                proc.kill()
            proc.join(START_TIMEOUT_S)
        in_flight = value if acked is None else acked + 1
        allowed = {stored if acked is None else acked, in_flight}  # the last acknowledged, or the one being stored
        value = in_flight + 1


@pytest.mark.slow
@pytest.mark.parametrize("device", ["/dev/zero", "/dev/full"])
def test_a_settings_link_to_a_device_is_refused_at_start_with_flat_memory(tmp_path, device):
    """One line and exit 2 under a data limit that twin-serial's imports fit in and that a read of
    the device would exceed at once (the link is not followed, so nothing is read). The limit is the
    memory check: a child's ru_maxrss starts at its parent's resident size (fork copies the high-water
    mark), so it cannot measure a child started from a large test process."""
    link = tmp_path / "eeprom.json"
    link.symlink_to(device)
    proc = subprocess.run([*CLI, "--settings", str(link)], capture_output=True, text=True, cwd=ROOT,
                          timeout=4 * START_TIMEOUT_S,  # only against a hang: no time is asserted
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_DATA, (DATA_LIMIT_BYTES,) * 2))
    assert (proc.returncode, proc.stdout, proc.stderr) == (
        2, "", f"twin-serial: error: settings file {link}: is a symbolic link; give the file itself (M500 never "
               "writes through a link)\n")
