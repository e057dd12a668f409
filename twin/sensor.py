"""The sensor chain: true sensor-node temperature -> NTC resistance -> divider -> ADC sample (10-bit,
an AVR's, unless told: a 32-bit board's is 12-bit).

This is the real part's physics (``firmware_port.thermistor``'s beta / Steinhart-Hart models),
not the firmware's table: the firmware only ever sees the integer samples made here. A
conversion is ``floor(1024 R / (R + Rp) + noise)`` clamped to 0..1023 (an ideal 10-bit ADC
floors), with optional Gaussian noise in LSB from a seeded generator. Faults:
- open thermistor: R infinite, the ADC reads 1023;
- shorted thermistor: R = 0, the ADC reads 0;
- detached thermistor: the bead hangs in air, so it reads its own node relaxing from the
  temperature it had toward ambient with ``detached_tau_s``.
Placement: an attached bead on a gradient (away from the heater, near the block's surface) sees
only ``1 - gradient_fraction`` of the sensor node's rise above ambient; 0 is a bead at the node.
"""

from __future__ import annotations

import numpy as np

from firmware_port.thermistor import ADC_COUNTS, Divider
from twin.limits import NOISE_MAX_LSB, checked
from twin.linear import TICK_S

OPEN, SHORT, DETACHED = "thermistor_open", "thermistor_short", "thermistor_detached"
DEFAULT_DIVIDER = Divider()  # frozen: a B3950 NTC with the board pull-up (firmware_port.thermistor)
DETACHED_TAU_S = 15.0  # a glass-bead thermistor in still air: tens of seconds


class SensorChain:
    """One heater's thermistor, divider and ADC pin."""

    def __init__(
        self,
        divider: Divider = DEFAULT_DIVIDER,
        noise_lsb: float = 0.0,
        rng: np.random.Generator | None = None,
        detached_tau_s: float = DETACHED_TAU_S,
        gradient_fraction: float = 0.0,
        adc_counts: int = ADC_COUNTS,
    ):
        """``adc_counts``: the ADC's full scale (1024 for 10 bits); noise is in its LSB."""
        noise_lsb = checked("noise_lsb", noise_lsb, 0.0, NOISE_MAX_LSB, "LSB")
        if not 0.0 <= gradient_fraction < 1.0:
            raise ValueError(f"gradient_fraction must be within [0, 1), got {gradient_fraction!r}")
        self.gradient_fraction = float(gradient_fraction)
        self.adc_counts = int(adc_counts)
        self.divider = divider
        self.noise_lsb = noise_lsb
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.detached_tau_s = detached_tau_s
        self.fault: str | None = None
        self._detached_c = 0.0  # the loose bead's temperature at _detached_tick
        self._detached_tick = 0
        self._ambient_c = 0.0

    def __repr__(self) -> str:
        return f"SensorChain({self.divider!r}, noise {self.noise_lsb:g} LSB" + \
            (f", {self.fault}" if self.fault else "") + \
            (f", gradient {self.gradient_fraction:g}" if self.gradient_fraction else "") + ")"

    def set_fault(self, fault: str | None, tick: int, sensor_c: float, ambient_c: float) -> None:
        """Schedule-time fault change; a detaching bead starts at the sensor node's temperature."""
        if fault not in (None, OPEN, SHORT, DETACHED):
            raise ValueError(f"not a thermistor fault: {fault!r}")
        if fault == DETACHED and self.fault != DETACHED:
            self._detached_c, self._detached_tick = sensor_c, tick
        self.fault = fault
        self._ambient_c = ambient_c

    def set_ambient(self, ambient_c: float, tick: int) -> None:
        """Ambient changed: re-anchor a detached bead's relaxation at its current temperature."""
        if self.fault == DETACHED:
            self._detached_c = float(self._bead_c(np.array([tick]))[0])
            self._detached_tick = tick
        self._ambient_c = ambient_c

    def _bead_c(self, ticks: np.ndarray) -> np.ndarray:
        age_s = (ticks - self._detached_tick) * TICK_S
        return self._ambient_c + (self._detached_c - self._ambient_c) * np.exp(-age_s / self.detached_tau_s)

    def analog(self, sensor_c: np.ndarray, ticks: np.ndarray) -> np.ndarray:
        """The unquantised reading ``1024 R / (R + Rp)`` of the bead (its placement, or a detached
        bead's own temperature), the shape of ``sensor_c``; no noise, no fault but a detached bead."""
        sensor_c = np.asarray(sensor_c, dtype=float)
        if self.fault == DETACHED:
            temps_c = np.broadcast_to(self._bead_c(ticks), sensor_c.shape)
        else:
            temps_c = sensor_c - self.gradient_fraction * (sensor_c - self._ambient_c)
        r = self.divider.part.resistance_ohm(temps_c)
        return self.adc_counts * r / (r + self.divider.pullup_ohm)

    def convert(self, sensor_c: np.ndarray, ticks: np.ndarray) -> np.ndarray:
        """ADC conversions (int array, the shape of ``sensor_c``) of the sensor node at the ticks.

        One noise draw per sample, in order; ``ticks`` broadcasts against ``sensor_c``.
        """
        sensor_c = np.asarray(sensor_c, dtype=float)
        noise = None
        if self.noise_lsb and self.fault not in (OPEN, SHORT):
            noise = self.noise_lsb * self.rng.standard_normal(sensor_c.shape)
        return self.convert_with(sensor_c, ticks, noise)

    def convert_with(self, sensor_c: np.ndarray, ticks: np.ndarray, noise: np.ndarray | None) -> np.ndarray:
        """``convert`` with the noise (in LSB, the shape of ``sensor_c``) given instead of drawn: a batch
        of lanes draws one stream and scales it per lane."""
        sensor_c = np.asarray(sensor_c, dtype=float)
        if self.fault == OPEN:
            return np.full(sensor_c.shape, self.adc_counts - 1)
        if self.fault == SHORT:
            return np.zeros(sensor_c.shape, dtype=int)
        analog = self.analog(sensor_c, ticks)
        if noise is not None:
            analog = analog + noise
        return np.clip(np.floor(analog), 0, self.adc_counts - 1).astype(np.int64)

    def lsb_per_c(self, temp_c: float) -> float:
        """ADC counts per kelvin at temp_c (the divider's slope, a central difference over 0.1 C):
        how finely a noiseless chain resolves that temperature."""
        r = self.divider.part.resistance_ohm(np.array([temp_c - 0.05, temp_c + 0.05]))
        analog = self.adc_counts * r / (r + self.divider.pullup_ohm)
        return float(abs(analog[0] - analog[1]) / 0.1)

    def samples(self, sensor_c: np.ndarray, ticks: np.ndarray) -> list[int]:
        """``convert`` as a list of ints, for a scalar board."""
        return self.convert(sensor_c, ticks).tolist()


def seeded_chains(count: int, seed: int, noise_lsb: float = 0.0) -> list[SensorChain]:
    """One chain per heater, each drawing its noise from its own stream spawned from ``seed``: what a
    ``Twin`` builds, so that a batch lane given the same seed sees the hotend chain's very numbers."""
    return [SensorChain(noise_lsb=noise_lsb, rng=np.random.default_rng(stream))
            for stream in np.random.SeedSequence(seed).spawn(count)]
