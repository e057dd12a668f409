"""Whether a printer's saved gains are Klipper's PID_CALIBRATE result, and the relay's Ku and Tu they imply.

PID_CALIBRATE (klippy/extras/pid_calibrate.py; firmware_port/klipper/pid_calibrate.py ``zn_from_relay``)
saves Ziegler-Nichols gains of its relay's Ku and Tu: Kp = 0.6 Ku 255, Ki = Kp / (0.5 Tu),
Kd = Kp 0.125 Tu, so Kd Ki = Kp^2 / 4 exactly, and SAVE_CONFIG writes each with three decimals. Gains
are PID_CALIBRATE's where that relation holds within their printed rounding: some (Kp', Ki', Kd') within
half a unit of the last printed digit of each has Ki' Kd' = Kp'^2 / 4 (the two products' ranges over
the rounding box overlap). Then Ku = Kp / 153 and Tu = 4 sqrt(Kd / Ki) (the geometric mean of 2 Kp / Ki
and 8 Kd / Kp, which agree for exact gains), each with the range the rounding allows.

Klipper's example configs ship gains that are one printer's calibration (EXAMPLE_GAINS); a log whose
heater runs them says nothing of its own heater's relay, so they are no evidence.

    saved = detect("24.831", "1.346", "114.532")  # SavedCalibration(ku=0.1623, tu_s=36.9, ...) or None
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

from firmware_port.klipper.heater import PID_PARAM_BASE

ZN_KP = 0.6  # Klipper's rule: Kp = 0.6 Ku (x PID_PARAM_BASE on the config scale)
RELATIVE_SLACK = 1e-9  # float arithmetic's own slack on the relation
# The gains Klipper's example configs (config/printer-*.cfg, config/example-*.cfg) ship: another printer's
# calibration, copied, not this heater's (README A: shreypatel's hotend and jc1rb's bed run them).
EXAMPLE_GAINS = (("22.2", "1.08", "114"), ("21.527", "1.063", "108.982"), ("54.027", "0.770", "948.182"))


@dataclass(frozen=True)
class SavedCalibration:
    """The relay point a PID_CALIBRATE's saved gains imply: Klipper's Ku (duty per degC, 0..1 scale: the
    gains' Kp / 153) and Tu, each with the range the gains' printed rounding allows."""

    ku: float
    tu_s: float
    ku_range: tuple[float, float]
    tu_range_s: tuple[float, float]

    def peak_to_peak_c(self, max_power: float) -> float:
        """The relay's swing at max_power: Ku = 4 max_power / (pi a), a half the peak-to-peak."""
        return 8.0 * max_power / (math.pi * self.ku)

    def text(self) -> str:
        return (f"Ku {self.ku * PID_PARAM_BASE:.4g} (x255), Tu {self.tu_s:.3g} s "
                f"({self.tu_range_s[0]:.4g}..{self.tu_range_s[1]:.4g} s by the printed rounding)")


def half_unit(text: str) -> float:
    """Half a unit of a printed number's last digit: its rounding ('1.346' -> 0.0005, '114' -> 0.5)."""
    try:
        exponent = Decimal(text.strip()).as_tuple().exponent
    except InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None
    assert isinstance(exponent, int)  # a finite number
    return 0.5 * 10.0 ** exponent


def detect(kp: str, ki: str, kd: str) -> SavedCalibration | None:
    """The relay point of printed gains where they are PID_CALIBRATE's (module docstring), else None."""
    values = [float(v) for v in (kp, ki, kd)]
    return detect_values(*values, *(half_unit(v) for v in (kp, ki, kd)))


def detect_values(kp: float, ki: float, kd: float, kp_half: float, ki_half: float, kd_half: float
                  ) -> SavedCalibration | None:
    """``detect`` of gains rounded to within the given half-units."""
    if min(kp - kp_half, ki - ki_half, kd - kd_half) <= 0.0:
        return None  # a gain its rounding could make zero or negative: no relay's
    products = ((ki - ki_half) * (kd - kd_half), (ki + ki_half) * (kd + kd_half))
    squares = ((kp - kp_half) ** 2 / 4.0, (kp + kp_half) ** 2 / 4.0)
    slack = RELATIVE_SLACK * squares[1]
    if products[0] > squares[1] + slack or squares[0] > products[1] + slack:
        return None
    base = ZN_KP * PID_PARAM_BASE
    tu_low = max(2.0 * (kp - kp_half) / (ki + ki_half), 8.0 * (kd - kd_half) / (kp + kp_half))
    tu_high = min(2.0 * (kp + kp_half) / (ki - ki_half), 8.0 * (kd + kd_half) / (kp - kp_half))
    tu_s = min(max(4.0 * math.sqrt(kd / ki), tu_low), tu_high)
    return SavedCalibration(kp / base, tu_s, ((kp - kp_half) / base, (kp + kp_half) / base), (tu_low, tu_high))


def example_gains(kp: str, ki: str, kd: str) -> bool:
    """Whether these are gains Klipper's example configs ship (EXAMPLE_GAINS)."""
    given = tuple(Decimal(v.strip()) for v in (kp, ki, kd))
    return any(given == tuple(Decimal(v) for v in gains) for gains in EXAMPLE_GAINS)


def from_config(section: dict[str, str]) -> tuple[SavedCalibration | None, str]:
    """A klippy.log heater section's saved gains as evidence: the relay point (None: no evidence) and what
    was found, in a phrase."""
    if section.get("control", "pid") != "pid" or not all(k in section for k in ("pid_kp", "pid_ki", "pid_kd")):
        return None, "no PID gains saved"
    kp, ki, kd = section["pid_kp"], section["pid_ki"], section["pid_kd"]
    if example_gains(kp, ki, kd):
        return None, (f"the saved gains {kp}/{ki}/{kd} are Klipper's example-config gains (another printer's "
                      "PID_CALIBRATE), no evidence of this heater")
    saved = detect(kp, ki, kd)
    if saved is None:
        product, square = float(ki) * float(kd), float(kp) ** 2 / 4.0
        return None, (f"the saved gains {kp}/{ki}/{kd} are not PID_CALIBRATE's: Kd Ki {product:.5g} against "
                      f"Kp^2/4 {square:.5g}, beyond their printed rounding")
    return saved, f"the saved gains {kp}/{ki}/{kd} are PID_CALIBRATE's: {saved.text()}"


__all__ = ["EXAMPLE_GAINS", "SavedCalibration", "detect", "detect_values", "example_gains", "from_config", "half_unit"]
