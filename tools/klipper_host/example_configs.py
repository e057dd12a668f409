"""Klipper's example configs on the twin MCU: how many it serves, and how many of those reach ready,
home and heat under the registry's klippy, each with only [mcu]'s serial line changed.

    python -m tools.klipper_host.example_configs [--speed 10] [NAME ...]

For each config/printer-*.cfg in klippy's package: the twin's refusal (one line), or a session at
--speed x real time: ready, G28, M104/M109 S200 and M140/M190 S60 (a config without a bed: the hotend
only). One line per config, then the counts. Under a few busy loops, homing at 10 x can miss
klippy's 25 ms trsync window ("Communication timeout during homing"): give --speed 1 to tell that
from the twin. About 40 s per served config at 10 x.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from pathlib import Path

from protocol.klipper_mcu.user_config import ConfigError, read_user_config
from tools.klipper_host.api import KlippyError
from tools.klipper_host.session import KLIPPY_VENV_ENV, KlipperSession, venv_command

STEPS = ("ready", "home", "heat")


def config_folder() -> Path:
    venv = venv_command(KLIPPY_VENV_ENV).parents[1]
    return next(venv.glob("lib/python3*/site-packages/klippy/config"))


def run_config(path: Path, speed: float) -> tuple[str, str]:
    """(the last step reached, or 'refused'; why it stopped there)."""
    try:
        config = read_user_config(path)
    except ConfigError as exc:
        return "refused", str(exc).split(": ", 1)[1]
    with tempfile.TemporaryDirectory() as folder:
        reached, why = "", ""
        try:
            with KlipperSession(Path(folder), speed=speed, mcu_args=("--printer-cfg", str(path))) as session:
                reached = "ready"
                session.api.gcode("G28", timeout_s=600)
                reached = "home"
                heaters = {h.heater for h in config.heaters}
                script = [g for g, heater in (("M104 S200", "hotend"), ("M140 S60", "bed"), ("M109 S200", "hotend"),
                                              ("M190 S60", "bed")) if heater in heaters]
                for line in script:
                    session.api.gcode(line, timeout_s=900)
                reached = "heat"
        except (KlippyError, TimeoutError, RuntimeError, OSError) as exc:
            why = " ".join(str(exc).split())[:160] + klippy_exception(Path(folder) / "klippy.log")
        return reached or "failed", why


def klippy_exception(log: Path) -> str:
    """klippy's last exception line (its type and message) where klippy.log has a traceback, else ''."""
    lines = log.read_text(errors="replace").splitlines() if log.exists() else []
    starts = [i for i, line in enumerate(lines) if line.startswith("Traceback")]
    if not starts:
        return ""
    error = next((line for line in lines[starts[-1] + 1:] if not line.startswith((" ", "Traceback"))), "")
    return f" [klippy.log: {error[:200]}]"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.klipper_host.example_configs", description=__doc__)
    parser.add_argument("--speed", type=float, default=10.0)
    parser.add_argument("names", nargs="*", help="config file names (default: every printer-*.cfg)")
    args = parser.parse_args(argv)
    folder = config_folder()
    paths = [folder / n for n in args.names] if args.names else sorted(folder.glob("printer-*.cfg"))
    counts: Counter[str] = Counter()
    for path in paths:
        reached, why = run_config(path, args.speed)
        counts[reached] += 1
        print(f"{path.name}: {reached}{': ' + why if why else ''}", flush=True)
    served = len(paths) - counts["refused"]
    at_least = {step: sum(counts[s] for s in STEPS[i:]) for i, step in enumerate(STEPS)}
    print(f"{len(paths)} configs: {counts['refused']} refused, {served} served; of those "
          + ", ".join(f"{at_least[s]} reached {s}" for s in STEPS) + f" (at {args.speed:g} x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
