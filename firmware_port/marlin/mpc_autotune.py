"""M306 T: Marlin 2.1.2.1's MPC autotune, one pass of its loops per ``poll()`` on the board's clock.

Source: Marlin 2.1.2.1 Marlin/src/module/temperature.cpp ``Temperature::MPC_autotune()`` and its
``housekeeping`` lambda and ``OnExit`` guard; core/language.h (STR_MPC_*). Marlin runs three
blocking loops; each ``poll()`` here is one pass of the current one (the fresh reading, the 1 s
report, then the loop's own test), so the board drives it as it drives M303:

1. fan at 255, heaters off: every 10 s, once the reading no longer falls, ambient is the mean of
   the last two tests;
2. fan off, full power (soft PWM 127, target shown as 200): from the first reading >= 100 C one
   sample a second (16 at most, then every other one kept and the spacing doubled) until >= 200 C;
   three equally spaced samples give the asymptote, the block's responsiveness b, A = P/(T_inf - T_amb),
   C = A/b and R from the sensor's initial lag; the model's block is put where it should be now;
3. MPC holds the target the model gives the block (an int16, truncated), run every MPC_dT by
   millis(): 20 s to settle, then 20 s of energy (heater energy plus the block's stored heat,
   with the first C) at fan 0, the same at fan 255; A and F from the mean powers over
   (target - ambient), then the asymptote P/A, b, C and R again. The reading must stay within
   t3 - 15 .. target + 15 C, else "Temperature error" ends the loop early (and the result is
   printed all the same, as 2.1.2.1 does).

On exit (done, interrupted by M108): target 0, heater off, fan off. The controller's constants and
modelled temperatures are written as Marlin writes ``MPC_t`` and ``MPCHeaterInfo`` in place: the
new constants stay in use (M500 stores them). Float maths is float32 in Marlin's order; exp and
log are rounded from double (avr-libc's may differ in the last bit).
"""

from __future__ import annotations

import math
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from firmware_port.fixed import INT16_MAX, INT16_MIN, wrap_u8, wrap_u32
from firmware_port.marlin.board import HOTEND_CHANNEL
from firmware_port.marlin.mpc import MPC_DT_F32, MPC_MAX, MpcConstants, MpcController
from firmware_port.marlin.protection import time_elapsed
from firmware_port.marlin.serial import format_float
from firmware_port.thermistor import TEMP_ONE

if TYPE_CHECKING:  # the board hosts the tune; the tune drives the board's hotend and fan
    from firmware_port.marlin.board import MarlinBoard

F32 = np.float32

# core/language.h (Marlin 2.1.2.1)
STR_MPC_AUTOTUNE = "MPC Autotune"
STR_MPC_AUTOTUNE_START = " start for E"  # " start for " STR_E, then the extruder's index
STR_MPC_AUTOTUNE_INTERRUPTED = " interrupted!"
STR_MPC_AUTOTUNE_FINISHED = " finished! Put the constants below into Configuration.h"
STR_MPC_COOLING_TO_AMBIENT = "Cooling to ambient"
STR_MPC_HEATING_PAST_200 = "Heating to over 200C"
STR_MPC_MEASURING_AMBIENT = "Measuring ambient heatloss at "
STR_MPC_TEMPERATURE_ERROR = "Temperature error"

# temperature.cpp MPC_autotune()
REPORT_INTERVAL_MS = 1000  # housekeeping: print_heater_states() every second
AMBIENT_TEST_MS = 10_000  # the cooling loop's test interval
SAMPLE_INTERVAL_MS = 1000  # heat-up samples, times sample_distance
SAMPLES_MAX = 16  # celsius_float_t temp_samples[16]
SAMPLE_FROM_C = 100.0  # "Record samples between 100C and 200C"
HEAT_TO_C = 200.0
SETTLE_MS = 20_000  # settle_time
TEST_MS = 20_000  # test_duration
TEMP_WINDOW_C = 15.0  # the loop ends unless t3 - 15 <= T <= target + 15
FAN_FULL = 255


class Phase(Enum):
    COOLING = "cooling to ambient"
    HEATING = "heating past 200 C"
    TRANSFER = "measuring the ambient heat loss"


def _exp(x: np.float32) -> np.float32:
    with np.errstate(all="ignore"):
        return F32(np.exp(np.float64(x)))


def _log(x: np.float32) -> np.float32:
    with np.errstate(all="ignore"):
        return F32(np.log(np.float64(x)))


def _float_to_int16(x: np.float32) -> int:
    """celsius_t = float: truncation; C leaves NaN or out-of-range undefined, the twin gives 0."""
    return int(x) if np.isfinite(x) and INT16_MIN <= int(x) <= INT16_MAX else 0


def _add_dt_ms(ms: int) -> int:
    """``next_test_ms = ms + MPC_dT * 1000``: the sum in float32, stored back in a millis_t."""
    return wrap_u32(int(F32(F32(ms) + F32(MPC_DT_F32 * F32(1000)))))


class MpcAutotune:
    """Marlin's M306 T on the board's hotend; the board calls ``poll`` on every main-loop pass
    and reads ``amount`` (the hotend's soft PWM) after it, as it runs M303's ``Autotune``."""

    gains: tuple[float, float, float] | None = None  # no PID gains for M303 U1's path to apply

    def __init__(self, board: MarlinBoard) -> None:
        controller = board.hotend.controller
        if not isinstance(controller, MpcController):
            raise ValueError(f"M306 T needs MPC on the hotend, not {type(controller).__name__}")
        self.board, self.mpc = board, controller
        self.phase = Phase.COOLING
        self.amount = 0
        self.done = self.succeeded = False
        self.ms = self.next_report_ms = self.next_test_ms = 0
        self.current_c = self.ambient_c = F32(0)  # current_temp, ambient_temp (float)
        self.samples: list[np.float32] = []  # temp_samples[0 .. sample_count)
        self.sample_distance = 1  # uint16
        self.heat_start_ms = 0
        self.t1_time_s = F32(0)
        self.t1 = self.t2 = self.t3 = F32(0)
        self.interval = 0  # sample_count >> 1: samples from t1 to t2 (and t2 to t3)
        self.settle_end_ms = self.test_end_ms = 0
        self.energy_j = [F32(0), F32(0)]  # total_energy_fan0, total_energy_fan255
        self.fan0_done = False
        self.last_c = F32(0)

    # -- what the board calls --------------------------------------------------------------

    def __repr__(self) -> str:
        return f"MpcAutotune(M306 T, {self.phase.value}, done={self.done}, succeeded={self.succeeded})"
    def start(self, now_ms: int) -> None:
        """Before the first loop: the start line, heaters off, fan 255, "Cooling to ambient"."""
        board = self.board
        board.console.writeln(f"{STR_MPC_AUTOTUNE}{STR_MPC_AUTOTUNE_START}0")
        board.disable_all_heaters()  # after gcode.home_all_axes(true); the axes are the printer's
        board.fan_speed = FAN_FULL
        board.console.writeln(STR_MPC_COOLING_TO_AMBIENT)
        self.ms = self.next_report_ms = now_ms
        self.next_test_ms = wrap_u32(now_ms + AMBIENT_TEST_MS)
        self.current_c = self.ambient_c = self._reading()

    def poll(self, now_ms: int, temp_q5: int | None) -> None:
        """One pass of the running loop; temp_q5 only when a fresh reading arrived."""
        if self.done:
            return
        self._housekeeping(now_ms, temp_q5)
        if self.phase is Phase.COOLING:
            self._cooling_pass()
        elif self.phase is Phase.HEATING:
            self._heating_pass()
        else:
            self._transfer_pass()

    def next_deadline_ms(self) -> int:
        """The next time a pass without a fresh reading acts: the report or the loop's test."""
        return min(self.next_report_ms, self.next_test_ms)

    def cancel(self) -> None:
        """M108 (wait_for_heatup = false): housekeeping says so on its next pass, then the exit."""
        if not self.done:
            self.board.console.writeln(f"{STR_MPC_AUTOTUNE}{STR_MPC_AUTOTUNE_INTERRUPTED}")
            self._exit()

    # -- the loops ---------------------------------------------------------------------------
    def _reading(self) -> np.float32:
        return F32(F32(self.board.hotend.temp_q5) / F32(TEMP_ONE))

    def _housekeeping(self, now_ms: int, temp_q5: int | None) -> None:
        self.ms = now_ms
        if temp_q5 is not None:
            self.current_c = F32(F32(temp_q5) / F32(TEMP_ONE))
        if time_elapsed(now_ms, self.next_report_ms):
            self.next_report_ms = wrap_u32(self.next_report_ms + REPORT_INTERVAL_MS)
            self.board.console.writeln(self.board.heater_states())

    def _cooling_pass(self) -> None:
        if not time_elapsed(self.ms, self.next_test_ms):
            return
        if self.current_c >= self.ambient_c:
            self.ambient_c = F32(F32(self.ambient_c + self.current_c) / F32(2))
            self._start_heating()
            return
        self.ambient_c = self.current_c
        self.next_test_ms = wrap_u32(self.next_test_ms + AMBIENT_TEST_MS)

    def _start_heating(self) -> None:
        board = self.board
        board.fan_speed = 0
        self.mpc.ambient_c = self.ambient_c  # hotend.modeled_ambient_temp
        board.console.writeln(STR_MPC_HEATING_PAST_200)
        board.hotend.target_c = int(HEAT_TO_C)  # "So M105 looks nice": no clamp, no watch
        self.amount = MPC_MAX >> 1
        self.heat_start_ms = self.next_test_ms = self.ms
        self.phase = Phase.HEATING

    def _heating_pass(self) -> None:
        if not time_elapsed(self.ms, self.next_test_ms):
            return
        if self.current_c >= F32(SAMPLE_FROM_C):
            if len(self.samples) == SAMPLES_MAX:  # too many samples: space them more widely
                self.samples = self.samples[::2]
                self.sample_distance *= 2
            if not self.samples:
                self.t1_time_s = F32(F32(wrap_u32(self.ms - self.heat_start_ms)) / F32(1000))
            self.samples.append(self.current_c)
        if self.current_c >= F32(HEAT_TO_C):
            self._start_transfer()
            return
        self.next_test_ms = wrap_u32(self.next_test_ms + SAMPLE_INTERVAL_MS * self.sample_distance)

    def _start_transfer(self) -> None:
        """The first estimate from three equally spaced samples, then MPC to the block's estimate."""
        self.amount = 0
        count = wrap_u8((len(self.samples) + 1) // 2 * 2 - 1)  # an odd count: a middle sample

        def sample(i: int) -> np.float32:
            return self.samples[i] if i < len(self.samples) else F32(math.nan)  # else: beyond the array

        self.t1, self.t2, self.t3 = sample(0), sample((count - 1) >> 1), sample(count - 1)
        self.interval = count >> 1
        with np.errstate(all="ignore"):
            asymp_c = self._asymptote()
            rate = self._responsiveness(asymp_c)
            p = F32(self.mpc.constants.heater_power_w)
            a = F32(F32(F32(p * F32(MPC_MAX)) / F32(255)) / F32(asymp_c - self.ambient_c))
            c = F32(a / rate)
            r = self._sensor_responsiveness(rate, asymp_c)
            self.mpc.constants = MpcConstants(float(p), float(c), float(r), float(a), 0.0,
                                              self.mpc.constants.filament_heat_capacity_j_k_mm)
            elapsed_s = F32(F32(F32(-rate) * F32(wrap_u32(self.ms - self.heat_start_ms))) / F32(1000))
            self.mpc.block_c = F32(asymp_c + F32(F32(self.ambient_c - asymp_c) * _exp(elapsed_s)))
        self.mpc.sensor_c = self.current_c
        self.board.console.writeln(f"{STR_MPC_MEASURING_AMBIENT}{format_float(self.mpc.block_c)}")
        self.board.hotend.target_c = _float_to_int16(self.mpc.block_c)
        self.next_test_ms = _add_dt_ms(self.ms)
        self.settle_end_ms = wrap_u32(self.ms + SETTLE_MS)
        self.test_end_ms = wrap_u32(self.settle_end_ms + TEST_MS)
        self.last_c = self.current_c
        self.phase = Phase.TRANSFER

    def _transfer_pass(self) -> None:
        ms = self.ms
        if time_elapsed(ms, self.next_test_ms):
            self.amount = self.board.controller_output(HOTEND_CHANNEL, ms) >> 1
            settled, ended = time_elapsed(ms, self.settle_end_ms), time_elapsed(ms, self.test_end_ms)
            if settled and not ended:
                self._add_energy(1 if self.fan0_done else 0)
            elif ended and not self.fan0_done:
                self.board.fan_speed = FAN_FULL
                self.settle_end_ms = wrap_u32(ms + SETTLE_MS)
                self.test_end_ms = wrap_u32(self.settle_end_ms + TEST_MS)
                self.fan0_done = True
            elif ended:
                return self._finish()
            self.last_c = self.current_c
            self.next_test_ms = _add_dt_ms(self.next_test_ms)
        target_c = F32(self.board.hotend.target_c)
        if not F32(self.t3 - F32(TEMP_WINDOW_C)) <= self.current_c <= F32(target_c + F32(TEMP_WINDOW_C)):
            self.board.console.writeln(STR_MPC_TEMPERATURE_ERROR)
            self._finish()

    def _add_energy(self, fan: int) -> None:
        """P amount/127 MPC_dT + (last - current) C: the heater's energy and what the block lost."""
        constants = self.mpc.constants
        heater_j = F32(F32(F32(F32(constants.heater_power_w) * F32(self.amount)) / F32(127)) * MPC_DT_F32)
        stored_j = F32(F32(self.last_c - self.current_c) * F32(constants.block_heat_capacity_j_k))
        self.energy_j[fan] = F32(self.energy_j[fan] + F32(heater_j + stored_j))

    # -- the estimates ---------------------------------------------------------------------------
    def _asymptote(self) -> np.float32:
        t1, t2, t3 = self.t1, self.t2, self.t3
        return F32(F32(F32(t2 * t2) - F32(t1 * t3)) / F32(F32(F32(F32(2) * t2) - t1) - t3))

    def _responsiveness(self, asymp_c: np.float32) -> np.float32:
        """b = -log((t2 - T_inf) / (t1 - T_inf)) / (sample_distance (sample_count >> 1))."""
        ratio = F32(F32(self.t2 - asymp_c) / F32(self.t1 - asymp_c))
        return F32(F32(-_log(ratio)) / F32(self.sample_distance * self.interval))

    def _sensor_responsiveness(self, rate: np.float32, asymp_c: np.float32) -> np.float32:
        """R = b / (1 - (T_amb - T_inf) exp(-b t1_time) / (t1 - T_inf)): the sensor's lag at t1."""
        lag = F32(F32(F32(self.ambient_c - asymp_c) * _exp(F32(F32(-rate) * self.t1_time_s))) / F32(self.t1 - asymp_c))
        return F32(rate / F32(F32(1) - lag))

    def _finish(self) -> None:
        """A and F from the mean powers, the asymptote and the rest again; the four lines."""
        mpc = self.mpc
        target_c = F32(self.board.hotend.target_c)
        with np.errstate(all="ignore"):
            power0_w, power255_w = (F32(F32(e * F32(1000)) / F32(TEST_MS)) for e in self.energy_j)
            a = F32(power0_w / F32(target_c - self.ambient_c))
            f = F32(power255_w / F32(target_c - self.ambient_c))
            p = F32(mpc.constants.heater_power_w)
            asymp_c = F32(self.ambient_c + F32(F32(F32(p * F32(MPC_MAX)) / F32(255)) / a))
            rate = self._responsiveness(asymp_c)
            c, r = F32(a / rate), self._sensor_responsiveness(rate, asymp_c)
        mpc.constants = MpcConstants(float(p), float(c), float(r), float(a), float(F32(f - a)),
                                     mpc.constants.filament_heat_capacity_j_k_mm)
        console = self.board.console
        console.writeln(f"{STR_MPC_AUTOTUNE}{STR_MPC_AUTOTUNE_FINISHED}")
        console.writeln(f"MPC_BLOCK_HEAT_CAPACITY {format_float(c)}")
        console.writeln(f"MPC_SENSOR_RESPONSIVENESS {format_float(r, 4)}")
        console.writeln(f"MPC_AMBIENT_XFER_COEFF {format_float(a, 4)}")
        console.writeln(f"MPC_AMBIENT_XFER_COEFF_FAN255 {format_float(f, 4)}")
        self.succeeded = True
        self._exit()

    def _exit(self) -> None:
        """OnExit: target 0, heater off, fan off (the Z clearance is the printer's)."""
        self.board.hotend.target_c = 0
        self.amount = 0
        self.board.fan_speed = 0
        self.done = True
