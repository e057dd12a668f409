"""The twin MCU under the registry's klippy, run after run at one speed: how many runs hold and calibrate.

    python -m tools.klipper_host.soak [--speed 10] [--runs 10]

Each run is a fresh session on the heater-only board: PID_CALIBRATE at 200 C from rest, whose gains must fall
in the twin port's band (tools/klipper_host/calibration.py: the port's relay from rest; after a hold the relay
starts elsewhere and takes other cycles), then SET_HEATER_TEMPERATURE to 200 C, 150 s of printer time to
settle and a 3-minute hold that must stay within 1 C (docs/klipper.md's example gains on hotend_stock).
One line per run (what failed, and what lenient mode forgave), then the count; a failed run's session folder
(klippy.log, the MCU's log, printer.cfg) is kept under ``--keep`` and its line says where. Run it with the load
you want to know about beside it (two busy loops: ``python3 -c "while True: pass" &`` twice); no retry at a
slower speed.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from tools.klipper_host.api import KlippyApi, KlippyError
from tools.klipper_host.calibration import band, parse_pid_reply, twin_pid_calibrate, within_band
from tools.klipper_host.session import KlipperSession, missed_schedule

HOTEND = "heater_generic hotend"
TARGET_C = 200.0
SETTLE_S, HOLD_S, HOLD_BAND_C = 150.0, 180.0, 1.0  # printer seconds; the hold's band
HANG_S = 1800.0  # wall-clock hang guard for one wait (at 1 x the hold alone is 330 s)


def hold(api: KlippyApi) -> float:
    """The hold's largest deviation from the target (C), read as fast as klippy answers."""
    api.gcode(f"SET_HEATER_TEMPERATURE HEATER=hotend TARGET={TARGET_C:g}")
    start_s = api.print_time()
    api.wait_print_time(start_s + SETTLE_S, HANG_S)
    worst, deadline = 0.0, time.monotonic() + HANG_S
    while api.print_time() < start_s + SETTLE_S + HOLD_S:
        if time.monotonic() > deadline:
            raise KlippyError("the hold never ended")
        worst = max(worst, abs(api.query(HOTEND)[HOTEND]["temperature"] - TARGET_C))
        time.sleep(0.05)
    api.gcode("SET_HEATER_TEMPERATURE HEATER=hotend TARGET=0")
    return worst


def run_once(speed: float, keep: Path) -> tuple[bool, str]:
    """(held and calibrated, what happened); a failed run's session folder is copied to ``keep``."""
    with tempfile.TemporaryDirectory() as folder:
        ok, what = _session(Path(folder), speed)
        if not ok:
            shutil.copytree(folder, keep, ignore=_not_files, dirs_exist_ok=True)
            what += f" (its logs: {keep})"
    return ok, what


def _not_files(folder: str, names: list[str]) -> list[str]:
    """What a kept session folder leaves out: klippy's API socket and the link to the MCU's pty, which cannot
    be copied (a socket, a device), only the files and folders."""
    return [name for name in names if not (Path(folder, name).is_file() or Path(folder, name).is_dir())]


def _session(folder: Path, speed: float) -> tuple[bool, str]:
    try:
        with KlipperSession(folder, speed=speed) as session:
            gains = parse_pid_reply(session.api.gcode(f"PID_CALIBRATE HEATER=hotend TARGET={TARGET_C:g}",
                                                      timeout_s=HANG_S))  # from rest, as the port's band
            worst_c = hold(session.api)
    except (KlippyError, TimeoutError, RuntimeError, OSError) as exc:
        off = missed_schedule(folder)
        return False, "failed: " + " ".join(str(exc).split())[:200] + (f" (off schedule: {off})" if off else "")
    forgiven = missed_schedule(folder) or "nothing late"  # the MCU's last lateness line, once stopped
    twin = twin_pid_calibrate(TARGET_C)
    held, calibrated = worst_c < HOLD_BAND_C, within_band(gains, twin)
    what = (f"hold within {worst_c:.2f} C ({'ok' if held else 'out of band'}), PID_CALIBRATE "
            f"{'in' if calibrated else 'out of'} the port's band ({gains} against {band(twin)}); {forgiven}")
    return held and calibrated, what


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.klipper_host.soak", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--speed", type=float, default=10.0, help="x real time (default 10)")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--keep", type=Path, default=Path("twin-out/soak"),
                        help="a failed run's logs go to KEEP/run-N (default twin-out/soak)")
    args = parser.parse_args(argv)
    if not args.speed > 0 or args.runs < 1:
        parser.error("--speed must be above 0 and --runs at least 1")
    passed = 0
    for k in range(1, args.runs + 1):
        ok, what = run_once(args.speed, args.keep / f"run-{k}")
        passed += ok
        print(f"run {k}: {what}", flush=True)
    print(f"{passed} of {args.runs} runs held {HOLD_S:g} s within {HOLD_BAND_C:g} C and calibrated at "
          f"{args.speed:g} x", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
