"""An STM32's own temperature sensor, as klippy's ``sensor_type: temperature_mcu`` reads it: the ADC channel
src/stm32 names ADC_TEMPERATURE (pin 0xfe), and for the families whose law klippy takes from factory
calibration, ``debug_read`` of those calibration half-words (klippy/extras/temperature_mcu.py's addresses).

The sensor is linear in the datasheets' typical values (volts at a temperature and a slope); the
calibration half-words are that same law read at their temperatures and reference, so klippy's line through
them gives back the twin chip's temperature. The chip runs CHIP_ABOVE_AMBIENT_C above the twin's ambient.
"""

from __future__ import annotations

from dataclasses import dataclass, field

TEMPERATURE_PIN = 0xFE  # src/stm32/adc.c ADC_TEMPERATURE_PIN
TEMPERATURE_PIN_NAME = "ADC_TEMPERATURE"
CHIP_ABOVE_AMBIENT_C = 10.0
ADC_FULL_V = 3.3


@dataclass(frozen=True)
class ChipSensor:
    """V(t) = volts + slope (t - at_c); ``calibration``: address -> (temperature, reference volts, full scale)."""

    volts: float
    at_c: float
    slope_v_per_c: float
    calibration: dict[int, tuple[float, float, int]] = field(default_factory=dict)

    def volts_at(self, temp_c: float) -> float:
        return self.volts + self.slope_v_per_c * (temp_c - self.at_c)

    def adc(self, temp_c: float, adc_max: int) -> int:
        """The 12-bit conversion of the channel at ``temp_c`` (3.3 V reference)."""
        return min(max(round(adc_max * self.volts_at(temp_c) / ADC_FULL_V), 0), adc_max)

    def read(self, address: int) -> int:
        """debug_read of a calibration half-word (0 elsewhere)."""
        if address not in self.calibration:
            return 0
        temp_c, reference_v, full = self.calibration[address]
        return round(full * self.volts_at(temp_c) / reference_v)


SENSORS = {  # by the MCU constant's prefix, as temperature_mcu.py picks its law
    "stm32f1": ChipSensor(1.43, 25.0, -0.0043),  # a fixed law: no calibration read
    "stm32f070": ChipSensor(1.43, 25.0, -0.0043, {0x1FFFF7B8: (30.0, 3.3, 4095)}),
    "stm32f4": ChipSensor(0.76, 25.0, 0.0025, {0x1FFF7A2C: (30.0, 3.3, 4095), 0x1FFF7A2E: (110.0, 3.3, 4095)}),
    "stm32g0": ChipSensor(0.76, 30.0, 0.0025, {0x1FFF75A8: (30.0, 3.0, 4095), 0x1FFF75CA: (130.0, 3.0, 4095)}),
    "stm32h7": ChipSensor(0.62, 30.0, 0.002, {0x1FF1E820: (30.0, 3.3, 65535), 0x1FF1E840: (110.0, 3.3, 65535)}),
}


def chip_sensor(mcu_constant: str) -> ChipSensor | None:
    """The sensor of a chip by its MCU constant (None: the twin gives that chip none, as Klipper's AVR build)."""
    return next((sensor for prefix, sensor in SENSORS.items() if mcu_constant.startswith(prefix)), None)
