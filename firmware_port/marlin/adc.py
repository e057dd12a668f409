"""Marlin's ADC state machine in the temperature ISR (Marlin 2.1.x Marlin/src/HAL/AVR/timers.h and module/temperature.cpp Temperature::isr()), for AVR.

One round is MIN_ADC_ISR_LOOPS = 10 ISRs: StartSampling, then a Prepare/Measure pair per
sensor (the conversion starts in Prepare and is read in Measure), then SensorsReady padding.
Each conversion is added to the sensor's accumulator; every OVERSAMPLENR-th StartSampling hands
the sums over as raw values (``readings_ready``). As in Marlin, the counter starts at 0, so the
very first reading after reset sums 15 samples, later ones 16.

The sample-and-hold captures the pin in the Prepare ISR, so that is when the port is asked.
Every Measure falls in the same round as its Prepare, before the next StartSampling, so adding
the conversion at Prepare gives the same sums as adding it at Measure; that lets ``skip`` run
many ISRs at once from samples taken in bulk.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

from firmware_port.marlin.constants import MIN_ADC_ISR_LOOPS, OVERSAMPLENR

if TYPE_CHECKING:
    import numpy as np


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

    def __init__(self, n_channels: int, port: AdcPort | None):
        """port is None for a sequencer driven only by ``skip`` (the fast engines sample in bulk)."""
        if 1 + 2 * n_channels > MIN_ADC_ISR_LOOPS:
            raise ValueError("more sensors than fit a 10-ISR round")
        self.port = port
        self.n_channels = n_channels
        self.phase = 0
        self.temp_count = 0
        self.acc = [0] * n_channels
        self.raw = [0] * n_channels
        self.raw_ready = False

    def __repr__(self) -> str:
        return f"AdcSequencer({self.n_channels} channels, phase {self.phase}, round {self.temp_count}, raw {self.raw})"

    def tick(self) -> None:
        """The ADC part of one temperature ISR."""
        phase = self.phase
        if phase == 0:
            self._start_sampling()
        elif phase < 2 * self.n_channels and phase & 1:  # Prepare: sample-and-hold now
            if self.port is None:
                raise RuntimeError("this AdcSequencer has no port: drive it with skip(), not tick()")
            channel = phase >> 1
            self.acc[channel] += self.port.sample(channel)
        self.phase = phase + 1 if phase + 1 < MIN_ADC_ISR_LOOPS else 0

    def sample_offsets(self, n_ticks: int) -> list[range]:
        """For each channel, the offsets (0..n_ticks-1) of the next ISRs that sample it."""
        return [
            range((2 * channel + 1 - self.phase) % MIN_ADC_ISR_LOOPS, n_ticks, MIN_ADC_ISR_LOOPS)
            for channel in range(self.n_channels)
        ]

    def ticks_to_reading(self) -> int:
        """How many ISRs until (and including) the one that hands over the next reading."""
        to_start = (MIN_ADC_ISR_LOOPS - self.phase) % MIN_ADC_ISR_LOOPS
        rounds = OVERSAMPLENR - 1 - self.temp_count  # StartSamplings after the next one
        return to_start + rounds * MIN_ADC_ISR_LOOPS + 1

    def skip(self, n_ticks: int, samples: Sequence[Sequence[int] | np.ndarray]) -> None:
        """``n_ticks`` ISRs at once, given each channel's conversions at ``sample_offsets``
        (ints, or an array with one row per conversion for lanes run in lockstep).

        Equivalent to ``n_ticks`` calls of ``tick()`` with a port returning those samples.
        """
        offsets = self.sample_offsets(n_ticks)
        taken = [0] * self.n_channels
        first_start = (MIN_ADC_ISR_LOOPS - self.phase) % MIN_ADC_ISR_LOOPS
        n_starts = len(range(first_start, n_ticks, MIN_ADC_ISR_LOOPS))
        # The j-th StartSampling (from 0) brings temp_count to temp_count + j + 1: a reading
        # is handed over whenever that reaches OVERSAMPLENR.
        j = OVERSAMPLENR - 1 - self.temp_count
        while j < n_starts:
            self._accumulate(samples, offsets, taken, first_start + j * MIN_ADC_ISR_LOOPS)
            self._readings_ready()
            j += OVERSAMPLENR
        self._accumulate(samples, offsets, taken, n_ticks)
        self.temp_count = (self.temp_count + n_starts) % OVERSAMPLENR
        self.phase = (self.phase + n_ticks) % MIN_ADC_ISR_LOOPS

    def _accumulate(self, samples, offsets, taken, before: int) -> None:
        """Add each channel's samples taken before offset ``before`` that are not added yet."""
        for channel, offs in enumerate(offsets):
            count = len(offs[: max(0, before - offs.start + MIN_ADC_ISR_LOOPS - 1) // MIN_ADC_ISR_LOOPS])
            if count > taken[channel]:
                self.acc[channel] += sum(samples[channel][taken[channel] : count])
                taken[channel] = count

    def _start_sampling(self) -> None:
        self.temp_count += 1
        if self.temp_count >= OVERSAMPLENR:
            self.temp_count = 0
            self._readings_ready()

    def _readings_ready(self) -> None:
        """Copy the sums to raw unless the main loop has not taken the last ones (Marlin drops them)."""
        if not self.raw_ready:
            self.raw = list(self.acc)
            self.raw_ready = True
        self.acc = [0] * self.n_channels
