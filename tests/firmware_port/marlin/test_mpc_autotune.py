"""M306 T on the board (firmware_port/marlin/mpc_autotune.py): Marlin 2.1.2.1's sequence (fan 255
while cooling, full power with the target shown as 200 C, MPC holding the block's estimate with the
fan off then at 255 for 20 + 20 s each, everything off at the end), the constants it finds on
Marlin's own model, and its exits: M108, a temperature out of the window, a build without MPC."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_port.marlin.board import HOTEND_CHANNEL
from firmware_port.marlin.mpc import MpcConstants, MpcController
from firmware_port.marlin.mpc_autotune import (
    STR_MPC_COOLING_TO_AMBIENT,
    STR_MPC_HEATING_PAST_200,
    STR_MPC_TEMPERATURE_ERROR,
    MpcAutotune,
    Phase,
)
from twin.engine import Twin
from twin.plants import SPECS

FINISHED = "MPC Autotune finished! Put the constants below into Configuration.h"
POLL_S = 1.0


def start_tune(twin: Twin) -> MpcAutotune:
    tune = MpcAutotune(twin.board)
    tune.start(twin.board.now_ms)
    twin.board.begin_tune(tune, HOTEND_CHANNEL)
    return tune


def run_tune(twin: Twin, tune: MpcAutotune, limit_s: float = 3600.0) -> None:
    while not tune.done and twin.time_s < limit_s:
        twin.run_until(twin.time_s + POLL_S)
    assert tune.done, f"still {tune.phase.value} after {limit_s} s"
    twin.run_until(twin.time_s + 2.0)  # the board takes the heater back


def event_time(twin: Twin, text: str) -> float:
    return next(t for t, line in twin.result().events if line.startswith(text))


@pytest.fixture(scope="module")
def tuned():
    """M306 T on the hotend preset (Marlin's MPC model with its Configuration.h constants)."""
    twin = Twin.create("mpc", hotend="hotend", bed="bed")
    twin.board.fan_speed = 100  # whatever the fan did before, the tune sets it
    tune = start_tune(twin)
    run_tune(twin, tune)
    return twin, tune


def test_the_sequence_of_phases(tuned):
    twin, tune = tuned
    result = twin.result()
    t, hotend = result.t_s, result.hotend
    heating_s, measuring_s = event_time(twin, STR_MPC_HEATING_PAST_200), event_time(twin, "Measuring ambient")
    finished_s = event_time(twin, FINISHED)
    cooling = t < heating_s
    assert np.all(result.fan[cooling] == 1.0) and np.all(hotend.duty[cooling] == 0)
    assert np.all(hotend.target_c[cooling] == 0)  # disable_all_heaters()
    heating = (t > heating_s + 0.2) & (t < measuring_s)
    assert np.all(result.fan[heating] == 0) and np.all(hotend.duty[heating] == 1.0)
    assert np.all(hotend.target_c[heating] == 200)  # "So M105 looks nice"
    assert hotend.measured_c[heating][-1] >= 199.0 and 9 <= heating_s < 12  # one 10 s test: it was at ambient
    holding = (t > measuring_s + 0.2) & (t < finished_s)
    held_target = hotend.target_c[holding]
    assert np.all(held_target == held_target[0]) and 200 < held_target[0] < 230  # the block's estimate, int16
    fan_255 = holding & (result.fan == 1.0)
    # 20 s to settle and 20 s of energy at fan 0, then the same at fan 255 (MPC_dT steps, millis())
    assert t[fan_255][0] - measuring_s == pytest.approx(40.0, abs=0.4)
    assert finished_s - measuring_s == pytest.approx(80.0, abs=0.6)
    after = t > finished_s + 0.2
    assert np.all(result.fan[after] == 0) and np.all(hotend.target_c[after] == 0) and np.all(hotend.duty[after] == 0)


def test_the_report_and_the_constants_found_on_marlins_own_model(tuned):
    twin, tune = tuned
    lines = twin.console.lines()
    assert lines[:2] == ["MPC Autotune start for E0", STR_MPC_COOLING_TO_AMBIENT]
    end = lines.index(FINISHED)
    names = [line.split(" ")[0] for line in lines[end + 1:end + 5]]
    assert names == ["MPC_BLOCK_HEAT_CAPACITY", "MPC_SENSOR_RESPONSIVENESS", "MPC_AMBIENT_XFER_COEFF",
                     "MPC_AMBIENT_XFER_COEFF_FAN255"]
    spec = SPECS["hotend"]
    found = tune.mpc.constants  # written in place, as MPC_t is: in use from now on
    for value, plant in ((found.block_heat_capacity_j_k, spec.block_heat_capacity_j_k),
                         (found.sensor_responsiveness_per_s, spec.sensor_responsiveness_per_s),
                         (found.ambient_xfer_w_k, spec.ambient_xfer_w_k),
                         (found.fan_ambient_xfer_w_k, spec.fan_ambient_xfer_w_k)):
        assert abs(value - plant) <= 0.10 * plant  # Marlin's method is approximate: a 10 % bound
    assert found.heater_power_w == 40.0 and found.filament_heat_capacity_j_k_mm == pytest.approx(0.0056)
    assert tune.succeeded and twin.board.autotune is None
    reports = [line for line in lines if line.startswith(" T:")]
    assert len(reports) == pytest.approx(event_time(twin, FINISHED), abs=2)  # one a second


def test_the_same_run_twice_prints_the_same_transcript():
    def transcript() -> list[str]:
        twin = Twin.create("mpc", hotend="hotend")
        run_tune(twin, start_tune(twin))
        return twin.console.lines()

    assert transcript() == transcript()


def test_from_hot_it_waits_until_the_reading_stops_falling():
    twin = Twin.create("mpc", hotend="hotend")
    twin.plants[0].x[:] = 150.0  # a hotend just used
    twin.run(1.0)
    tune = start_tune(twin)
    run_tune(twin, tune)
    # fan 255 until a 10 s test sees no fall: near 30 C a noiseless reading steps by about 0.4 C and
    # the hotend cools by less than that in 10 s, so the "ambient" is a few degrees above the room's
    assert 300 < event_time(twin, STR_MPC_HEATING_PAST_200) < 900
    assert 25.0 < float(tune.ambient_c) < 32.0
    assert tune.succeeded and 0.05 < tune.mpc.constants.ambient_xfer_w_k < 0.09


def test_m108_interrupts_with_marlins_line_and_turns_everything_off():
    twin = Twin.create("mpc", hotend="hotend")
    tune = start_tune(twin)
    twin.run_until(30.0)
    assert tune.phase is Phase.HEATING and twin.board.amount(HOTEND_CHANNEL) == 127
    twin.board.cancel_autotune()
    assert twin.console.lines()[-1] == "MPC Autotune interrupted!"
    assert twin.board.autotune is None and twin.board.fan_speed == 0 and twin.board.target_c(HOTEND_CHANNEL) == 0
    assert twin.board.amount(HOTEND_CHANNEL) == 0 and not tune.succeeded


def test_a_reading_out_of_the_window_ends_the_hold_and_2_1_2_1_still_prints_a_result():
    twin = Twin.create("mpc", hotend="hotend")
    tune = start_tune(twin)
    while tune.phase is not Phase.TRANSFER:
        twin.run_until(twin.time_s + POLL_S)
    twin.set_heater_mode(HOTEND_CHANNEL, "heater_disconnected")  # it cools below t3 - 15 C
    run_tune(twin, tune)
    lines = twin.console.lines()
    error = lines.index(STR_MPC_TEMPERATURE_ERROR)
    assert lines[error + 1] == FINISHED and lines[error + 2].startswith("MPC_BLOCK_HEAT_CAPACITY ")
    assert twin.board.fan_speed == 0 and twin.board.target_c(HOTEND_CHANNEL) == 0


def test_m306_t_needs_mpc_on_the_hotend():
    twin = Twin.create("pid", hotend="hotend")
    with pytest.raises(ValueError, match="M306 T needs MPC on the hotend"):
        MpcAutotune(twin.board)
    assert isinstance(Twin.create("mpc").board.hotend.controller, MpcController)
    assert MpcConstants().m306().startswith("M306 E0 P40.00")
