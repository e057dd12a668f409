"""Marlin's ADC state machine in the temperature ISR (reference section 0), for AVR.

One round is MIN_ADC_ISR_LOOPS = 10 ISRs: StartSampling, then a Prepare/Measure pair per
sensor (the conversion starts in Prepare and is read in Measure), then SensorsReady padding.
Each Measure adds a 10-bit sample to the sensor's accumulator; every OVERSAMPLENR-th
StartSampling hands the sums over as raw values (``readings_ready``). As in Marlin, the counter
starts at 0, so the very first reading after reset sums 15 samples, later ones 16.
"""

from __future__ import annotations

from typing import Protocol

from firmware_port.marlin.constants import MIN_ADC_ISR_LOOPS, OVERSAMPLENR

ADC_MAX = 1023


class AdcPort(Protocol):
    """What the board's analog pins see: the twin implements this."""

    def sample(self, channel: int) -> int:
        """A 10-bit conversion (0..1023) of ``channel`` started now."""


class AdcSequencer:
    """Rounds of 10 ISRs over ``n_channels`` sensors.

    phase:       uint8, 0..9 position in the round (0 = StartSampling)
    temp_count:  uint8, 0..15 rounds since the last reading
    acc[i]:      uint16, running sum of samples (<= 16 * 1023)
    raw[i]:      uint16, the last completed sum, 0..16368
    raw_ready:   flag set by readings_ready, cleared by the main loop
    """

    def __init__(self, n_channels: int, port: AdcPort):
        if 1 + 2 * n_channels > MIN_ADC_ISR_LOOPS:
            raise ValueError("more sensors than fit a 10-ISR round")
        self.port = port
        self.n_channels = n_channels
        self.phase = 0
        self.temp_count = 0
        self.acc = [0] * n_channels
        self.raw = [0] * n_channels
        self.raw_ready = False
        self._conversion = 0

    def tick(self) -> None:
        """The ADC part of one temperature ISR."""
        phase = self.phase
        if phase == 0:
            self.temp_count += 1
            if self.temp_count >= OVERSAMPLENR:
                self.temp_count = 0
                self._readings_ready()
        elif phase <= 2 * self.n_channels:
            channel = (phase - 1) >> 1
            if phase & 1:  # Prepare: the sample-and-hold captures the pin now
                self._conversion = self.port.sample(channel)
            else:  # Measure: read the finished conversion
                self.acc[channel] += self._conversion
        self.phase = phase + 1 if phase + 1 < MIN_ADC_ISR_LOOPS else 0

    def _readings_ready(self) -> None:
        """Copy the sums to raw unless the main loop has not taken the last ones (Marlin drops them)."""
        if not self.raw_ready:
            self.raw = list(self.acc)
            self.raw_ready = True
        self.acc = [0] * self.n_channels
