"""Marlin's bang-bang heater control (Marlin 2.1.x Marlin/src/module/temperature.cpp manage_heated_bed()): no PID, full power or nothing."""

from __future__ import annotations

from firmware_port.lane_law import LaneLaw, record_dtype, register
from firmware_port.marlin.constants import BANG_MAX, BED_CHECK_INTERVAL_MS, BED_HYSTERESIS_C, MAX_BED_POWER
from firmware_port.thermistor import TEMP_FRAC_BITS


class BangBangHotend:
    """Hotend without PIDTEMP: BANG_MAX while below target, evaluated every reading, no hysteresis."""

    check_interval_ms = None
    STATE_BYTES = 0

    def reset(self) -> None:
        """Nothing to forget."""

    def __repr__(self) -> str:
        return f"BangBangHotend(on={BANG_MAX})"

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """``is_below_target()``: celsius < target."""
        return BANG_MAX if temp_q5 < target_c << TEMP_FRAC_BITS else 0


def bang_bang_lane(p, s, temp_q5, target_c, board):
    """``BangBangHotend.update`` on one lane of the compiled batch (no parameters, no state)."""
    return BANG_MAX if temp_q5 < target_c << TEMP_FRAC_BITS else 0


BANG_BANG_LAW = register(LaneLaw("bangbang", BangBangHotend, record_dtype(()), record_dtype(()),
                                 bang_bang_lane), check=False)


class BangBangBed:
    """Bed without PIDTEMPBED: run every BED_CHECK_INTERVAL (the board gates it, with the
    bed's runaway check); optional BED_LIMIT_SWITCHING holds the output inside +-1 C."""

    check_interval_ms = BED_CHECK_INTERVAL_MS
    STATE_BYTES = 1  # output: uint8, kept between checks when limit switching

    def __init__(self, limit_switching: bool = False):
        self.limit_switching = limit_switching
        self.output = 0

    def reset(self) -> None:
        """Start from off."""
        self.output = 0

    def __repr__(self) -> str:
        return f"BangBangBed(on={MAX_BED_POWER}, limit_switching={self.limit_switching}, output={self.output})"

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """MAX_BED_POWER below target, 0 above; with limit switching, unchanged within +-1 C."""
        if not self.limit_switching:
            self.output = MAX_BED_POWER if temp_q5 < target_c << TEMP_FRAC_BITS else 0
            return self.output
        band_q5 = (BED_HYSTERESIS_C - 1) << TEMP_FRAC_BITS
        target_q5 = target_c << TEMP_FRAC_BITS
        if temp_q5 > target_q5 + band_q5:
            self.output = 0
        elif temp_q5 < target_q5 - band_q5:
            self.output = MAX_BED_POWER
        return self.output
