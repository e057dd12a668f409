"""A plant against the printer's own PID_CALIBRATE: does its relay oscillate as the saved gains say the
heater's did (tools/tuning/calibration.py gives their Ku and Tu)?

The port's PID_CALIBRATE (KlipperTwin.pid_calibrate) runs on the plant from its fitted ambient with the
heater's own settings (max_power, sensor, pullup, smoothing: tools/validation/compare.py ``make_setup``) at
both ends of the band docs/validation.md section 3 uses (CALIBRATION_BAND_C: hotend 180..240 C, bed
50..100 C): no klippy.log states the temperature it was calibrated at. The plant reproduces the calibration
where somewhere in the band (the saved value within the goal of the span the two ends give, as section 3's
"within 15 % in the band") its Tu is within TU_GOAL_REL and its Ku within KU_GOAL_REL.

The goals are those of the twin's PID_CALIBRATE replay of a result line (tools/validation/m303_compare.py
GOALS["results"]: Tu 15 %, swing 30 %): saved gains are one result line. Ku = 4 max_power / (pi a) is the
swing's inverse, so its goal is the swing's, 30 %; the data back the wider goal: the relay's printed swing
scatters 13 % cycle to cycle against its Tu's 4 % (tools/ident/relay_points.py CYCLE_SCATTER_*, the
Artillery bed's six cycles), and PID_CALIBRATE keeps one cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_port.klipper.heater import PID_PARAM_BASE
from tools.ident.result import FitResult
from tools.tuning.calibration import SavedCalibration
from tools.validation import compare, m303_compare
from twin.klipper_twin import KlipperTwin
from twin.plants import Plant

TU_GOAL_REL, KU_GOAL_REL = m303_compare.GOALS["results"]


@dataclass(frozen=True)
class RelayCheck:
    """The twin's PID_CALIBRATE on one plant at the band's ends against the saved calibration."""

    band_c: tuple[float, float]
    tu_s: tuple[float, float]  # NaN where the twin cannot calibrate there (max_temp, a shutdown)
    ku: tuple[float, float]
    saved: SavedCalibration

    @property
    def tu_ok(self) -> bool:
        return in_band(self.saved.tu_s, self.tu_s, TU_GOAL_REL)

    @property
    def ku_ok(self) -> bool:
        return in_band(self.saved.ku, self.ku, KU_GOAL_REL)

    @property
    def passed(self) -> bool:
        return self.tu_ok and self.ku_ok

    def text(self) -> str:
        """One line: the twin's Tu and Ku over the band against the saved ones."""
        band = "..".join(f"{t:g}" for t in self.band_c)
        tu = "/".join(_num(t, ".3g") for t in self.tu_s)
        ku = "/".join(_num(k * PID_PARAM_BASE, ".3g") for k in self.ku)
        return (f"its PID_CALIBRATE at {band} C relays at Tu {tu} s where your PID_CALIBRATE saw "
                f"{self.saved.tu_s:.3g} s (goal {TU_GOAL_REL:.0%} in the band: {'pass' if self.tu_ok else 'miss'}); "
                f"Ku {ku} against {self.saved.ku * PID_PARAM_BASE:.3g} (goal {KU_GOAL_REL:.0%}: "
                f"{'pass' if self.ku_ok else 'miss'})")


def _num(value: float, fmt: str) -> str:
    return format(value, fmt) if math.isfinite(value) else "n/a"


def in_band(saved: float, twin: tuple[float, float], goal_rel: float) -> bool:
    """The saved value within goal_rel of the span the twin's finite values cover."""
    ends = [v for v in twin if math.isfinite(v)]
    return bool(ends) and min(ends) * (1.0 - goal_rel) <= saved <= max(ends) * (1.0 + goal_rel)


def twin_calibration(result: FitResult, info: compare.HeaterInfo, heater: str, target_c: float
                     ) -> tuple[float, float]:
    """(Tu, Ku) of the port's PID_CALIBRATE on the plant at target_c; NaNs where it does not finish."""
    ambient_c = result.ambient_c
    plant = Plant(result.model, result.spec(), ambient_c, ambient_c)
    twin = KlipperTwin([compare.make_setup(info, heater, plant)])
    try:
        got = twin.pid_calibrate(heater, target_c)
    except Exception:  # noqa: BLE001 - a shutdown, a target past max_temp, a timeout: no relay there
        return math.nan, math.nan
    return got.tu_s, got.ku


def check(result: FitResult, info: compare.HeaterInfo, heater: str, saved: SavedCalibration) -> RelayCheck:
    """The plant's PID_CALIBRATE at the band's ends against the saved calibration (module docstring)."""
    band = compare.CALIBRATION_BAND_C[heater]
    runs = [twin_calibration(result, info, heater, t) for t in band]
    return RelayCheck(band, (runs[0][0], runs[1][0]), (runs[0][1], runs[1][1]), saved)


__all__ = ["KU_GOAL_REL", "TU_GOAL_REL", "RelayCheck", "check", "in_band", "twin_calibration"]
