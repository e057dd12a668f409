"""Marlin's Model Predictive Control of a hotend (MPCTEMP), as Marlin 2.1.2.1 runs it on an AVR.

Sources (Marlin 2.1.2.1): Marlin/src/module/temperature.cpp ``get_pid_output_hotend()`` (its
MPCTEMP branch) and ``Temperature::init()``; temperature.h (``MPC_t``, ``MPCHeaterInfo``,
``MPC_dT``); gcode/temp/M306.cpp; module/settings.cpp (the defaults); Configuration.h (the MPC
section). avr-gcc's float and double are both IEEE single precision, so the law runs in
numpy.float32 in Marlin's operation order; the same code in float64 measures that order's rounding.

On each reading the model takes one step of ``MPC_dT``: the block gains ``P amount/127`` and
loses ``k (T_block - T_ambient)`` with ``k = A + fan/255 (F - A) + H e_speed``; the sensor node
follows the block at ``R``; both are pulled half way (MPC_SMOOTHING_FACTOR) to the reading. The
ambient estimate moves with that pull, by at least MPC_MIN_AMBIENT_CHANGE K/s, while the heater
is not saturated or the block is steady. The output is the power that brings the block to the
target in 2 s and then holds its loss, on the 0..255 scale of the board::

    controller = mpc_controller(40.0, 16.7, 0.22, 0.068, 0.097, 0.0056)  # M306 P C R A F H
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from firmware_port.controller import BoardInputs
from firmware_port.fixed import wrap_s32
from firmware_port.lane_law import LaneLaw, register
from firmware_port.marlin.constants import (
    ACTUAL_ADC_SAMPLES,
    BANG_MAX,
    E_MAX_FEEDRATE_MM_S,
    E_STEPS_PER_MM,
    OVERSAMPLENR,
    TEMP_TIMER_FREQUENCY,
)
from firmware_port.marlin.serial import format_float
from firmware_port.params import Param, ParamSpace
from firmware_port.thermistor import TEMP_ONE

F32 = np.float32

# Configuration.h, the MPCTEMP section (Marlin 2.1.2.1).
MPC_MAX = BANG_MAX  # (0..255) current to the nozzle while MPC is active
MPC_HEATER_POWER_W = 40.0  # MPC_HEATER_POWER
MPC_BLOCK_HEAT_CAPACITY_J_K = 16.7  # MPC_BLOCK_HEAT_CAPACITY
MPC_SENSOR_RESPONSIVENESS_PER_S = 0.22  # MPC_SENSOR_RESPONSIVENESS, K/s per K
MPC_AMBIENT_XFER_COEFF_W_K = 0.068  # MPC_AMBIENT_XFER_COEFF, fan off
MPC_AMBIENT_XFER_COEFF_FAN255_W_K = 0.097  # MPC_AMBIENT_XFER_COEFF_FAN255
FILAMENT_HEAT_CAPACITY_PERMM_J_K_MM = 5.6e-3  # 1.75 mm PLA
MPC_SMOOTHING_FACTOR = 0.5  # the pull of the model towards each reading
MPC_MIN_AMBIENT_CHANGE_K_S = 1.0  # the slowest the ambient estimate moves when it moves
MPC_STEADYSTATE_K_S = 0.5  # block rate below which the ambient estimate may move at full power
MPC_INIT_AMBIENT_MAX_C = 30.0  # get_pid_output_hotend(): "reasonable max room temperature"

# #define MPC_dT ((OVERSAMPLENR * float(ACTUAL_ADC_SAMPLES)) / (TEMP_TIMER_FREQUENCY)), as PID_dT
MPC_DT_F32 = F32(F32(OVERSAMPLENR * ACTUAL_ADC_SAMPLES) / F32(TEMP_TIMER_FREQUENCY))


def f32(x: float | np.floating) -> float:
    """The float32 nearest ``x``, as a Python float (what a float field of MPC_t can hold)."""
    return float(F32(x))


@dataclass(frozen=True)
class MpcConstants:
    """MPC_t: what M306 sets, M500 stores and M306 T measures, each a float32 value.

    Marlin keeps the fan's coefficient as its difference to A (``fan255_adjustment``), so an A
    set later moves the F that M306 reports: ``from_m306`` and ``with_m306`` take F itself.
    """

    heater_power_w: float = MPC_HEATER_POWER_W  # P
    block_heat_capacity_j_k: float = MPC_BLOCK_HEAT_CAPACITY_J_K  # C
    sensor_responsiveness_per_s: float = MPC_SENSOR_RESPONSIVENESS_PER_S  # R
    ambient_xfer_w_k: float = MPC_AMBIENT_XFER_COEFF_W_K  # A, part fan off
    fan255_adjustment_w_k: float = f32(F32(MPC_AMBIENT_XFER_COEFF_FAN255_W_K) - F32(MPC_AMBIENT_XFER_COEFF_W_K))
    filament_heat_capacity_j_k_mm: float = FILAMENT_HEAT_CAPACITY_PERMM_J_K_MM  # H

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            object.__setattr__(self, field.name, f32(getattr(self, field.name)))

    @classmethod
    def from_m306(cls, p: float, c: float, r: float, a: float, f: float, h: float) -> MpcConstants:
        """The constants an ``M306 P C R A F H`` line sets: F is the fan-255 coefficient itself."""
        return cls(p, c, r, a, f32(F32(f) - F32(a)), h)

    @property
    def fan_ambient_xfer_w_k(self) -> float:
        """F: the transfer coefficient at fan 255, A + fan255_adjustment in float32."""
        return f32(F32(self.ambient_xfer_w_k) + F32(self.fan255_adjustment_w_k))

    def with_m306(self, *, p: float | None = None, c: float | None = None, r: float | None = None,
                  a: float | None = None, f: float | None = None, h: float | None = None) -> MpcConstants:
        """M306's set branch: the given letters in its order (P, C, R, A, then F against the new A, H)."""
        new = dataclasses.replace(self, **{name: value for name, value in (
            ("heater_power_w", p), ("block_heat_capacity_j_k", c), ("sensor_responsiveness_per_s", r),
            ("ambient_xfer_w_k", a), ("filament_heat_capacity_j_k_mm", h)) if value is not None})
        if f is not None:
            new = dataclasses.replace(new, fan255_adjustment_w_k=f32(F32(f) - F32(new.ambient_xfer_w_k)))
        return new

    def m306(self) -> str:
        """M306_report()'s line after its two leading spaces: ``M306 E0 P40.00 C16.70 R0.2200 ...``."""
        return (f"M306 E0 P{format_float(self.heater_power_w)} C{format_float(self.block_heat_capacity_j_k)}"
                f" R{format_float(self.sensor_responsiveness_per_s, 4)} A{format_float(self.ambient_xfer_w_k, 4)}"
                f" F{format_float(self.fan_ambient_xfer_w_k, 4)} H{format_float(self.filament_heat_capacity_j_k_mm, 4)}")


DEFAULT_CONSTANTS = MpcConstants()


class MpcController:
    """Marlin 2.1.2.1's MPC hotend law behind the board's ``Controller`` and ``ReadsBoard``.

    State as Marlin's ``MPCHeaterInfo`` holds it (float32): ``ambient_c``, ``block_c`` and
    ``sensor_c`` are the modelled temperatures (block NaN until the first update, as
    ``Temperature::init()`` leaves it), ``e_position_steps`` is ``Temperature::mpc_e_position``
    (int32). ``constants`` are M306's (``defaults``: the build's Configuration.h, what M502 loads).
    The terms as last computed: ``block_delta_c`` (the model's block step), ``pull_c`` (the pull
    to the reading, ``delta_to_apply``) and ``power_w``. ``dtype=np.float64`` runs the same order
    in double.
    """

    check_interval_ms = None

    def __init__(self, constants: MpcConstants = DEFAULT_CONSTANTS, dtype: type[np.floating] = np.float32):
        self.f = dtype
        f = dtype
        self.defaults = constants
        self.dt = f(f(OVERSAMPLENR * ACTUAL_ADC_SAMPLES) / f(TEMP_TIMER_FREQUENCY))  # MPC_dT
        self._dt_per_127 = f(self.dt / f(127))  # (MPC_dT / 127)
        self._steady = f(f(MPC_STEADYSTATE_K_S) * self.dt)  # MPC_STEADYSTATE * MPC_dT
        self._min_change = f(f(MPC_MIN_AMBIENT_CHANGE_K_S) * self.dt)  # MPC_MIN_AMBIENT_CHANGE * MPC_dT
        self._per_255 = f(f(1) / f(255))  # RECIPROCAL(255)
        self._mm_per_step = f(f(1) / f(E_STEPS_PER_MM))  # planner.mm_per_step[E_AXIS]
        self._max_feedrate = f(E_MAX_FEEDRATE_MM_S)  # planner.settings.max_feedrate_mm_s[E_AXIS]
        self.constants = constants
        self.reset()

    @property
    def constants(self) -> MpcConstants:
        return self._constants

    @constants.setter
    def constants(self, constants: MpcConstants) -> None:
        """M306, M500/M501 and M306 T write MPC_t; the model's state carries on."""
        self._constants = constants
        f = self.f
        self._p, self._c, self._r = f(constants.heater_power_w), f(constants.block_heat_capacity_j_k), \
            f(constants.sensor_responsiveness_per_s)
        self._a, self._fan_adj = f(constants.ambient_xfer_w_k), f(constants.fan255_adjustment_w_k)
        self._h = f(constants.filament_heat_capacity_j_k_mm)
        self._r_dt = f(self._r * self.dt)  # (sensor_responsiveness * MPC_dT)

    def __repr__(self) -> str:
        return f"MpcController({self.constants!r}, {np.dtype(self.f).name}, block_c={float(self.block_c):.2f}, " \
               f"sensor_c={float(self.sensor_c):.2f})"

    def reset(self) -> None:
        """The MCU's reset: the model starts again from the first reading (Temperature::init())."""
        f = self.f
        self.ambient_c, self.block_c, self.sensor_c = f(0), f(math.nan), f(0)
        self.e_position_steps = 0
        self.inputs = BoardInputs(0, 0, 0)
        self.block_delta_c = self.pull_c = self.power_w = f(0)

    def read_board(self, inputs: BoardInputs) -> None:
        """What get_pid_output_hotend() reads: soft_pwm_amount, fan_speed[0], stepper.position(E)."""
        self.inputs = inputs

    def update(self, temp_q5: int, target_c: int, now_ms: int = 0) -> int:
        """One step on a reading: ``(int)get_pid_output_hotend()``, 0..255 (a NaN output is 0:
        C leaves its cast undefined, the twin turns the heater off)."""
        out = self.update_float(temp_q5, target_c)
        return 0 if math.isnan(out) else int(out)

    def update_float(self, temp_q5: int, target_c: int) -> np.floating:
        """The law, returning Marlin's float output (before the cast)."""
        f = self.f
        with np.errstate(all="ignore"):  # M306 accepts any constant: a zero gives inf/NaN, as on the AVR
            celsius = f(f(temp_q5) / f(TEMP_ONE))
            if math.isnan(self.block_c):  # at startup, initialise the modelled temperatures
                self.ambient_c = min(f(MPC_INIT_AMBIENT_MAX_C), celsius)
                self.block_c = self.sensor_c = celsius
            k = self._transfer_coefficient()
            self._step_model(celsius, k)
            power = f(0)
            if target_c != 0:  # plan the power that reaches the target in 2 s, then holds the loss
                power = f(f(f(f(target_c) - self.block_c) * self._c) / f(2))
                power = f(power - f(f(self.ambient_c - self.block_c) * k))
            self.power_w = power
            out = f(f(f(power * f(254)) / self._p) + f(1))  # "correct quantization into 0 to 127"
        return f(0) if out < 0 else f(MPC_MAX) if out > MPC_MAX else out  # constrain(): NaN passes

    def _transfer_coefficient(self) -> np.floating:
        """k = A + fan/255 (F - A) + H e_speed, with the E stepper's feed since the last step (a
        jump beyond the E axis' max feedrate is taken as homing, a retraction waits to be fed back)."""
        f = self.f
        k = f(self._a + f(f(f(self.inputs.fan_speed) * self._per_255) * self._fan_adj))
        e_position = self.inputs.e_position_steps
        e_speed = f(f(f(wrap_s32(e_position - self.e_position_steps)) * self._mm_per_step) / self.dt)
        if abs(e_speed) > self._max_feedrate:
            self.e_position_steps = e_position
        elif e_speed > f(0):
            k = f(k + f(e_speed * self._h))
            self.e_position_steps = e_position
        return k

    def _step_model(self, celsius: np.floating, k: np.floating) -> None:
        """The block and sensor step, the pull to the reading, then the ambient estimate."""
        f = self.f
        amount = self.inputs.amount
        block_delta = f(f(f(f(amount) * self._p) * self._dt_per_127) / self._c)
        block_delta = f(block_delta + f(f(f(f(self.ambient_c - self.block_c) * k) * self.dt) / self._c))
        self.block_c = f(self.block_c + block_delta)
        self.sensor_c = f(self.sensor_c + f(f(self.block_c - self.sensor_c) * self._r_dt))
        delta = f(f(celsius - self.sensor_c) * f(MPC_SMOOTHING_FACTOR))
        self.block_c = f(self.block_c + delta)
        self.sensor_c = f(self.sensor_c + delta)
        self.block_delta_c, self.pull_c = block_delta, delta
        # only near steady state: the output not clipped, or the asymptote reached
        if 1 <= amount <= 126 or abs(f(block_delta + delta)) < self._steady:
            step = max(delta, self._min_change) if delta > f(0) else min(delta, -self._min_change)
            self.ambient_c = f(self.ambient_c + step)


# -- the compiled batch's lane law (firmware_port/lane_law.py): the float32 controller ----------------
# MpcController's float32 constants of the build (Configuration.h and the planner), as it computes them.
DT_PER_127 = F32(MPC_DT_F32 / F32(127))
STEADY = F32(F32(MPC_STEADYSTATE_K_S) * MPC_DT_F32)
MIN_CHANGE = F32(F32(MPC_MIN_AMBIENT_CHANGE_K_S) * MPC_DT_F32)
PER_255 = F32(F32(1) / F32(255))
MM_PER_STEP = F32(F32(1) / F32(E_STEPS_PER_MM))
MAX_FEEDRATE = F32(E_MAX_FEEDRATE_MM_S)
INIT_AMBIENT_MAX = F32(MPC_INIT_AMBIENT_MAX_C)
SMOOTHING = F32(MPC_SMOOTHING_FACTOR)
TEMP_ONE_F32, ZERO, ONE, TWO, F254, MPC_MAX_F32 = F32(TEMP_ONE), F32(0), F32(1), F32(2), F32(254), F32(MPC_MAX)
# MPC_t as the controller holds it (P, C, R * MPC_dT, A, F - A, H) and MPCHeaterInfo's state.
LANE_PARAMS = np.dtype([(name, np.float32) for name in ("_p", "_c", "_r_dt", "_a", "_fan_adj", "_h")])
LANE_STATE = np.dtype([("ambient_c", np.float32), ("block_c", np.float32), ("sensor_c", np.float32),
                       ("e_position_steps", np.int64)])


def _transfer_lane(p, s, board):
    """``MpcController._transfer_coefficient`` on a lane: every operation on float32 operands."""
    k = p._a + np.float32(board.fan_speed) * PER_255 * p._fan_adj
    e_speed = np.float32(wrap_s32(board.e_position_steps - s.e_position_steps)) * MM_PER_STEP / MPC_DT_F32
    if abs(e_speed) > MAX_FEEDRATE:
        s.e_position_steps = board.e_position_steps
    elif e_speed > ZERO:
        k = k + e_speed * p._h
        s.e_position_steps = board.e_position_steps
    return k


def _model_lane(p, s, amount, celsius, k):
    """``MpcController._step_model`` on a lane."""
    block_delta = np.float32(amount) * p._p * DT_PER_127 / p._c
    block_delta = block_delta + (s.ambient_c - s.block_c) * k * MPC_DT_F32 / p._c
    s.block_c = s.block_c + block_delta
    s.sensor_c = s.sensor_c + (s.block_c - s.sensor_c) * p._r_dt
    delta = (celsius - s.sensor_c) * SMOOTHING
    s.block_c = s.block_c + delta
    s.sensor_c = s.sensor_c + delta
    if 1 <= amount <= 126 or abs(block_delta + delta) < STEADY:
        s.ambient_c = s.ambient_c + (max(delta, MIN_CHANGE) if delta > ZERO else min(delta, -MIN_CHANGE))


def mpc_lane(p, s, temp_q5, target_c, board):
    """``MpcController.update`` on one lane of the compiled batch (float32 throughout): 0..255."""
    celsius = np.float32(temp_q5) / TEMP_ONE_F32
    if math.isnan(s.block_c):
        s.ambient_c = min(INIT_AMBIENT_MAX, celsius)
        s.block_c = celsius
        s.sensor_c = celsius
    k = _transfer_lane(p, s, board)
    _model_lane(p, s, board.amount, celsius, k)
    power = ZERO
    if target_c != 0:
        power = (np.float32(target_c) - s.block_c) * p._c / TWO
        power = power - (s.ambient_c - s.block_c) * k
    out = power * F254 / p._p + ONE
    if math.isnan(out):
        return 0
    return 0 if out < ZERO else MPC_MAX if out > MPC_MAX_F32 else int(out)


# Every constant is read from the first reading on: lanes share a run only with their twins.
MPC_LAW = register(LaneLaw("mpc", MpcController, LANE_PARAMS, LANE_STATE, mpc_lane, reads_board=True,
                           fits=lambda c: c.f is np.float32), check=False)


def mpc_controller(heater_power_w: float = MPC_HEATER_POWER_W,
                   block_heat_capacity_j_k: float = MPC_BLOCK_HEAT_CAPACITY_J_K,
                   sensor_responsiveness_per_s: float = MPC_SENSOR_RESPONSIVENESS_PER_S,
                   ambient_xfer_w_k: float = MPC_AMBIENT_XFER_COEFF_W_K,
                   fan_ambient_xfer_w_k: float = MPC_AMBIENT_XFER_COEFF_FAN255_W_K,
                   filament_heat_capacity_j_k_mm: float = FILAMENT_HEAT_CAPACITY_PERMM_J_K_MM) -> MpcController:
    """An MPC hotend controller from its model constants in M306's order (P C R A F H): the
    parameter vector a tuner varies (tuning MPC is identifying its model)."""
    return MpcController(MpcConstants.from_m306(heater_power_w, block_heat_capacity_j_k, sensor_responsiveness_per_s,
                                                ambient_xfer_w_k, fan_ambient_xfer_w_k, filament_heat_capacity_j_k_mm))


MPC_SEARCH_FACTOR = 10.0  # tuning bounds: each identified constant from 1/10 to 10 x its default


def mpc_space(defaults: MpcConstants = DEFAULT_CONSTANTS) -> ParamSpace:
    """MPC as a tunable family: its model constants C, R, A, F (M306's letters), searched on log scales
    within 1/10..10 x ``defaults``; P and H stay (the heater's rating, the filament's capacity). Tuning
    MPC is identifying its model: the firmware's own way is M306 T (``autotune``)."""
    def factory(c: float, r: float, a: float, f: float) -> MpcController:
        return MpcController(MpcConstants.from_m306(defaults.heater_power_w, c, r, a, f,
                                                    defaults.filament_heat_capacity_j_k_mm))

    def held(c: float, r: float, a: float, f: float) -> tuple[float, float, float, float]:
        return f32(c), f32(r), f32(a), f32(f)  # MPC_t holds float32

    values = (("block_heat_capacity_j_k", "J/K", defaults.block_heat_capacity_j_k),
              ("sensor_responsiveness_per_s", "1/s", defaults.sensor_responsiveness_per_s),
              ("ambient_xfer_w_k", "W/K", defaults.ambient_xfer_w_k),
              ("fan_ambient_xfer_w_k", "W/K", defaults.fan_ambient_xfer_w_k))
    params = tuple(Param(name, unit, value / MPC_SEARCH_FACTOR, value * MPC_SEARCH_FACTOR, value, log=True)
                   for name, unit, value in values)
    return ParamSpace("mpc", params, factory, held=held, autotune="M306 T")
