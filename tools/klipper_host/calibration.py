"""PID_CALIBRATE two ways on one plant: through the registry's klippy on the twin MCU, and through
the twin's own port of klippy's loop (``KlipperTwin.pid_calibrate``) with klippy 0.12's version
switches, the MCU's ADC and thermistor; and the band within which the two must agree.

The band: klippy takes its relay peaks from the 0.3 s sensor reports, so where the relay starts
relative to the report grid (when the command lands, the ADC's sample phase against the plant's
1.024 ms tick) can move a peak by a report: 1 % of a 30 s period, and the same in Ki and Kd; the
swing's amplitude moves by a fraction of an ADC step. BAND_REL covers a few such shifts. On a plant
at rest the relay starts in the same place whenever the command comes, and the two agree exactly
(docs/klipper.md's table, ``python -m tools.docs.klipper_table``).
"""

from __future__ import annotations

import re

from firmware_port.klipper import KLIPPY_0_12, HeaterConfig
from protocol.klipper_mcu.board import DEFAULT_PLANTS, PULLUP_OHM, WIRING
from protocol.klipper_mcu.printer_cfg import EXAMPLE_PID
from twin.klipper_twin import ATMEGA2560, HeaterSetup, KlipperTwin, PidCalibrateResult
from twin.plants import make_plant

BAND_REL = 0.03  # klippy's gains within 3 % of the twin port's (see above)
PID_REPLY = re.compile(r"pid_Kp=([-\d.]+) pid_Ki=([-\d.]+) pid_Kd=([-\d.]+)")


def twin_pid_calibrate(target_c: float, plant: str = DEFAULT_PLANTS["hotend"]) -> PidCalibrateResult:
    """The port's PID_CALIBRATE on the twin MCU's hotend: its section, plant, sensor and 10-bit ADC."""
    hotend = next(w for w in WIRING if w.heater == "hotend")
    config = HeaterConfig(hotend.section, 0.0, hotend.max_temp_c, pid_kp=EXAMPLE_PID[0], pid_ki=EXAMPLE_PID[1],
                          pid_kd=EXAMPLE_PID[2], **KLIPPY_0_12)
    twin = KlipperTwin([HeaterSetup(config, make_plant(plant), pullup_ohm=PULLUP_OHM)], mcu=ATMEGA2560)
    return twin.pid_calibrate("hotend", target_c)


def parse_pid_reply(lines: list[str]) -> tuple[float, float, float]:
    """(Kp, Ki, Kd) from PID_CALIBRATE's reply; ValueError if the reply has none."""
    for line in lines:
        found = PID_REPLY.search(line)
        if found:
            kp, ki, kd = (float(v) for v in found.groups())
            return kp, ki, kd
    raise ValueError(f"no 'PID parameters' line in PID_CALIBRATE's reply: {lines}")


def within_band(got: tuple[float, float, float], twin: tuple[float, float, float]) -> bool:
    """Every gain within BAND_REL of the twin port's."""
    return all(abs(g - t) <= BAND_REL * abs(t) for g, t in zip(got, twin))
