"""PID_CALIBRATE two ways on one plant: through the registry's klippy on the twin MCU, and through
the twin's own port of klippy's loop (``KlipperTwin.pid_calibrate``) with klippy 0.12's version
switches, the MCU's ADC and thermistor; and the band within which the two must agree.

The band: PID_CALIBRATE's answer is the cycle of median length (ties by position), and its cycles
are timed by 0.3 s reports, so several cycles share the median length to within a report while
their swings differ: each peak is the reading nearest to the true peak, which lands differently in
every cycle (on the stock MPC hotend, maxima of 203.08 and 203.64 C alternate: 6 % in Kp). Which
of them Klipper takes turns on float ties in the peak times, so the band is every answer the port's
own relay offers from a cycle within one report of the median length, widened by BAND_SLACK_REL.
From a plant at rest the relay starts in the same place whenever the command comes, and klippy
often gives the port's very answer (docs/klipper.md's table, ``python -m tools.docs.klipper_table``).
"""

from __future__ import annotations

import re

from firmware_port.klipper import KLIPPY_0_12, HeaterConfig, relay_ku, zn_from_relay
from firmware_port.klipper.heater import REPORT_TIME
from firmware_port.klipper.pid_calibrate import FIRST_FINAL_POS
from protocol.klipper_mcu.board import DEFAULT_PLANTS, PULLUP_OHM, WIRING
from protocol.klipper_mcu.printer_cfg import EXAMPLE_PID
from twin.klipper_twin import ATMEGA2560, HeaterSetup, KlipperTwin, PidCalibrateResult
from twin.plants import make_plant

BAND_SLACK_REL = 0.005  # beyond the candidates' range: the 3 printed decimals and float noise
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


def candidates(result: PidCalibrateResult) -> list[tuple[float, float, float]]:
    """The gains of every cycle PID_CALIBRATE could have taken: within one report of the median length."""
    peaks = result.peaks
    cycles = [(peaks[pos][1] - peaks[pos - 2][1], pos) for pos in range(FIRST_FINAL_POS, len(peaks))]
    median_s = sorted(cycles)[len(cycles) // 2][0]
    return [zn_from_relay(relay_ku(peaks[pos][0] - peaks[pos - 1][0]), cycle_s)
            for cycle_s, pos in cycles if abs(cycle_s - median_s) <= REPORT_TIME]


def band(result: PidCalibrateResult) -> list[tuple[float, float]]:
    """(low, high) of Kp, Ki and Kd over the candidates, widened by BAND_SLACK_REL."""
    options = candidates(result)
    return [(min(c[k] for c in options) * (1 - BAND_SLACK_REL), max(c[k] for c in options) * (1 + BAND_SLACK_REL))
            for k in range(3)]


def within_band(got: tuple[float, float, float], result: PidCalibrateResult) -> bool:
    """Every gain within the band of the twin port's calibration."""
    return all(low <= g <= high for g, (low, high) in zip(got, band(result)))
