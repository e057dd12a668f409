"""Marlin's software PWM for heaters (Marlin 2.1.x Marlin/src/module/temperature.cpp Temperature::isr() SoftPWM), SOFT_PWM_SCALE 0, no dither.

Heaters are always driven by digital writes in the temperature ISR: a 7-bit counter runs
0..126 (one period = 127 ISRs = 130 ms); at the wrap each channel latches its amount and goes
high if it is non-zero; on later ticks it goes low once the counter reaches the latched amount.
So the on-time in a period is exactly ``amount`` ISRs, and a new amount waits for the next wrap.
"""

from __future__ import annotations

import numpy as np

from firmware_port.marlin.constants import SOFT_PWM_MAX, SOFT_PWM_PERIOD_TICKS


class SoftPwm:
    """The ISR's PWM state for ``n_channels`` heaters.

    pwm_count: uint8, 0..127 (starts at _BV(SOFT_PWM_SCALE) = 1)
    amount[i]: uint8, 0..127, written by the main loop
    count[i]:  uint8, the amount latched at the last wrap
    pins[i]:   the heater output pin levels
    """

    def __init__(self, n_channels: int):
        self.pwm_count = 1
        self.amount = [0] * n_channels
        self.count = [0] * n_channels
        self.pins = [False] * n_channels

    def __repr__(self) -> str:
        return f"SoftPwm(amount {self.amount}, count {self.pwm_count})"

    def set_amount(self, channel: int, amount: int) -> None:
        """Main loop writes ``soft_pwm_amount`` (0..127)."""
        if not 0 <= amount <= SOFT_PWM_MAX:
            raise ValueError(f"soft PWM amount {amount} outside 0..{SOFT_PWM_MAX}")
        self.amount[channel] = amount

    def tick(self) -> None:
        """The PWM part of one temperature ISR."""
        tmp = self.pwm_count
        if tmp >= SOFT_PWM_PERIOD_TICKS:
            tmp -= SOFT_PWM_PERIOD_TICKS
            for ch, amount in enumerate(self.amount):
                self.count[ch] = amount
                self.pins[ch] = amount > 0
        else:
            for ch, latched in enumerate(self.count):
                if latched <= tmp:
                    self.pins[ch] = False
        self.pwm_count = tmp + 1

    def waveform(self, channel: int, n_ticks: int) -> np.ndarray:
        """The pin level after each of the next ``n_ticks`` ISRs (amounts as they are now).

        The counter seen by ISR i is ``(pwm_count + i) % 127``: 0 is the wrap, where the amount
        is latched; before the first wrap the pin can only fall, at the old latched count.
        """
        counter = (self.pwm_count + np.arange(n_ticks)) % SOFT_PWM_PERIOD_TICKS
        first_wrap = (SOFT_PWM_PERIOD_TICKS - self.pwm_count) % SOFT_PWM_PERIOD_TICKS
        before = counter < self.count[channel] if self.pins[channel] else np.zeros(n_ticks, bool)
        after = counter < self.amount[channel]
        return np.where(np.arange(n_ticks) < first_wrap, before, after)

    def skip(self, n_ticks: int) -> None:
        """Run ``n_ticks`` ISRs at once: the same state as ``n_ticks`` calls of ``tick()``."""
        if n_ticks <= 0:
            return
        first_wrap = (SOFT_PWM_PERIOD_TICKS - self.pwm_count) % SOFT_PWM_PERIOD_TICKS
        last = (self.pwm_count + n_ticks - 1) % SOFT_PWM_PERIOD_TICKS  # counter of the last ISR
        for ch in range(len(self.amount)):
            if first_wrap < n_ticks:
                self.count[ch] = self.amount[ch]
                self.pins[ch] = last < self.amount[ch]
            elif self.pins[ch]:
                self.pins[ch] = last < self.count[ch]
        self.pwm_count = last + 1

    def all_off(self) -> None:
        """disable_all_heaters(): amounts 0 and pins written LOW at once."""
        for ch in range(len(self.amount)):
            self.amount[ch] = 0
            self.count[ch] = 0
            self.pins[ch] = False
