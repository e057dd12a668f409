"""Properties of Marlin's MPC law (firmware_port/marlin/mpc.py), one per invariant:

- the output is within 0..255 (PID_MAX) for any constants M306 can set and any inputs;
- the ambient estimate moves only where the law allows it (output not clipped, or the block
  steady), in the pull's direction (a zero pull lowers it), by at least MPC_MIN_AMBIENT_CHANGE
  x MPC_dT and at most max(|pull|, that): a bounded rate, never a jump;
- on the plant it models (the twin's plant built from the controller's own constants), the law
  holds the target: the reading's time-mean within one ADC count of it;
- each step in float32, in Marlin's order, lies within a derived bound of the same step in
  float64: a running error bound carried through every operation of the law itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from firmware_port.controller import BoardInputs
from firmware_port.fixed import INT32_MAX, INT32_MIN
from firmware_port.marlin.mpc import MPC_DT_F32, MpcConstants, MpcController
from firmware_port.thermistor import B3950_TABLE, TEMP_ONE
from twin.engine import Twin
from twin.plants import make_plant

U32 = 2.0 ** -24  # float32's unit roundoff: a correctly rounded operation errs by at most U32 |result|
U64 = 2.0 ** -53  # the reference's own
MIN_CHANGE = float(MPC_DT_F32)  # MPC_MIN_AMBIENT_CHANGE (1 K/s) x MPC_dT

float32s = st.floats(width=32, allow_nan=False)  # anything an M306 value can parse to, infinities included
temps_q5 = st.integers(-40 * TEMP_ONE, 400 * TEMP_ONE)
inputs = st.builds(BoardInputs, st.integers(0, 127), st.integers(0, 255), st.integers(INT32_MIN, INT32_MAX))


def physical(p=(20.0, 80.0), c=(5.0, 30.0), r=(0.1, 0.5), a=(0.03, 0.15)):
    """Constants of a real hotend: M306's ranges for cartridges of 20..80 W."""
    return st.builds(lambda *v: MpcConstants.from_m306(*v), st.floats(*p), st.floats(*c), st.floats(*r),
                     st.floats(*a), st.floats(0.15, 0.3), st.floats(0.0, 0.02))


@given(st.tuples(float32s, float32s, float32s, float32s, float32s, float32s),
       st.lists(st.tuples(temps_q5, st.integers(0, 450), inputs), min_size=1, max_size=20))
def test_the_output_is_within_0_to_255(values, steps):
    mpc = MpcController(MpcConstants(*values))
    for temp_q5, target_c, board in steps:
        mpc.read_board(board)
        assert 0 <= mpc.update(temp_q5, target_c) <= 255


@given(physical(), st.lists(st.tuples(temps_q5, st.integers(0, 300), inputs), min_size=2, max_size=30))
def test_the_ambient_estimate_moves_by_at_least_the_minimum_and_at_most_the_pull(constants, steps):
    mpc = MpcController(constants)
    mpc.read_board(steps[0][2])
    mpc.update(steps[0][0], steps[0][1])
    steady = 0.5 * MIN_CHANGE  # MPC_STEADYSTATE (0.5 K/s) x MPC_dT
    for temp_q5, target_c, board in steps[1:]:
        before = float(mpc.ambient_c)
        mpc.read_board(board)
        mpc.update(temp_q5, target_c)
        moved, pull = float(mpc.ambient_c) - before, float(mpc.pull_c)
        allowed = 1 <= board.amount <= 126 or abs(float(mpc.block_delta_c) + pull) < steady * (1 + U32)
        ulp = float(np.spacing(np.float32(max(abs(before), abs(float(mpc.ambient_c))))))  # the float32 sum rounds
        if not allowed:
            assert moved == 0.0
            continue
        assert math.copysign(1.0, moved) == (1.0 if pull > 0 else -1.0)  # a zero pull moves it down
        assert MIN_CHANGE - ulp <= abs(moved) <= max(abs(pull), MIN_CHANGE) + ulp


# -- steady state on the model it was given --------------------------------------------------------
HOLD_START_S, HOLD_END_S = 50.0, 150.0


@pytest.mark.slow
@settings(max_examples=40)  # each example is 150 s of the twin (~0.3 s): 40 keep the test under ~15 s
@given(physical(), st.floats(15.0, 35.0), st.integers(0, 255), st.floats(0.0, 3.0), st.integers(100, 250))
def test_on_the_plant_it_models_the_law_holds_the_target(constants, ambient_c, fan, flow_mm_s, target_c):
    k_w_k = constants.ambient_xfer_w_k + fan / 255 * constants.fan255_adjustment_w_k \
        + constants.filament_heat_capacity_j_k_mm * flow_mm_s
    assume(target_c - ambient_c < 0.8 * constants.heater_power_w / k_w_k)  # held below 80 % duty
    plant = make_plant("hotend", ambient_c=ambient_c, initial_c=target_c, power_w=constants.heater_power_w,
                       block_heat_capacity_j_k=constants.block_heat_capacity_j_k,
                       sensor_responsiveness_per_s=constants.sensor_responsiveness_per_s,
                       ambient_xfer_w_k=constants.ambient_xfer_w_k,
                       fan_ambient_xfer_w_k=constants.fan_ambient_xfer_w_k,
                       filament_heat_capacity_j_k_mm=constants.filament_heat_capacity_j_k_mm)
    twin = Twin([plant], "mpc", controllers=[MpcController(constants)])
    twin.set_ambient(ambient_c)
    twin.board.fan_speed = fan
    twin.flow_mm_s = flow_mm_s
    twin.board.set_target(0, target_c)
    run = twin.run(HOLD_END_S).hotend
    hold = run.t_s >= HOLD_START_S
    error_c = run.measured_c[hold] - target_c
    count_c = B3950_TABLE.count_c(target_c)
    # The noiseless reading steps by one ADC count; the law dithers across the levels around the
    # target (the 50 % pull of a quantised reading): its time-mean lies within one count.
    assert abs(float(np.mean(error_c))) <= count_c
    assert twin.board.halted is False


# -- float32 in Marlin's order against float64 --------------------------------------------------------
class Bounded:
    """A float64 value with a bound on how far the float32 evaluation of the same expression can be
    from it. The law wraps every operation's result in its dtype, so passed as the dtype this type
    adds float32's rounding exactly where Marlin's float rounds: running error analysis."""

    __slots__ = ("v", "e")

    def __init__(self, x, e: float | None = None):
        if e is not None:
            self.v, self.e = float(x), e
        elif isinstance(x, Bounded):  # a rounding to float32
            self.v, self.e = x.v, x.e + U32 * (abs(x.v) + x.e)
        else:  # a constant or input converted to float32 (exact when representable)
            self.v = float(x)
            self.e = 0.0 if math.isnan(self.v) else abs(float(np.float32(self.v)) - self.v)

    @staticmethod
    def _of(x) -> Bounded:
        return x if isinstance(x, Bounded) else Bounded(x, 0.0)

    def _result(self, v: float, e: float) -> Bounded:
        return Bounded(v, e + U64 * abs(v))

    def __add__(self, other):
        o = self._of(other)
        return self._result(self.v + o.v, self.e + o.e)

    def __sub__(self, other):
        o = self._of(other)
        return self._result(self.v - o.v, self.e + o.e)

    def __mul__(self, other):
        o = self._of(other)
        return self._result(self.v * o.v, abs(self.v) * o.e + abs(o.v) * self.e + self.e * o.e)

    def __truediv__(self, other):
        o = self._of(other)
        assert abs(o.v) > o.e, "a divisor within its error of zero"
        v = self.v / o.v
        return self._result(v, (self.e + abs(v) * o.e) / (abs(o.v) - o.e))

    def __neg__(self):
        return Bounded(-self.v, self.e)

    def __abs__(self):
        return Bounded(abs(self.v), self.e)

    def __float__(self):
        return self.v

    def __lt__(self, other):
        return self.v < float(other)

    def __gt__(self, other):
        return self.v > float(other)

    def __le__(self, other):
        return self.v <= float(other)

    def __ge__(self, other):
        return self.v >= float(other)


def _set_state(mpc: MpcController, state: tuple[float, float, float], e_steps: int) -> None:
    mpc.ambient_c, mpc.block_c, mpc.sensor_c = (mpc.f(np.float32(x)) for x in state)
    mpc.e_position_steps = e_steps


@given(physical(), st.tuples(*[st.floats(-20.0, 400.0, width=32)] * 3), st.integers(-10000, 10000),
       temps_q5, st.integers(0, 300), st.integers(0, 127), st.integers(0, 255), st.integers(-2000, 2000))
def test_float32_in_marlins_order_is_within_the_running_error_bound_of_float64(
        constants, state, e_steps, temp_q5, target_c, amount, fan, e_moved):
    single, bounded = MpcController(constants), MpcController(constants, dtype=Bounded)
    for mpc in (single, bounded):
        _set_state(mpc, state, e_steps)
        mpc.read_board(BoardInputs(amount, fan, e_steps + e_moved))
    out = single.update_float(temp_q5, target_c)
    ref = bounded.update_float(temp_q5, target_c)
    # Branches where float32 and float64 could decide differently (a pull or a steady-state test
    # within its error of the threshold, a feed at 25 mm/s) fall outside a one-path bound.
    pull, steady = bounded.pull_c, abs(bounded.block_delta_c + bounded.pull_c)
    assume(abs(pull.v) > pull.e and abs(steady.v - 0.5 * MIN_CHANGE) > steady.e + 1e-9)
    assume(abs(abs(e_moved) * 0.002 / MIN_CHANGE - 25.0) > 1e-3)
    for got, want in ((out, ref), (single.block_c, bounded.block_c), (single.sensor_c, bounded.sensor_c),
                      (single.ambient_c, bounded.ambient_c), (single.power_w, bounded.power_w)):
        assert abs(float(got) - want.v) <= want.e, (float(got), want.v, want.e)
    assert ref.e <= 1e-3 * max(1.0, abs(ref.v))  # and the bound is tight enough to mean something
