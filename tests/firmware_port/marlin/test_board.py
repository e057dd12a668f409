"""The board end to end on a crude plant: control, gating, protection trips and their text."""

import re

import pytest

from firmware_port.marlin.bangbang import BangBangBed, BangBangHotend
from firmware_port.marlin.board import BED_CHANNEL, HOTEND_CHANNEL, MarlinBoard
from firmware_port.marlin.constants import ISR_PERIOD_S, TICKS_PER_READING
from firmware_port.thermistor import Divider

DT_S = float(ISR_PERIOD_S)
AMBIENT_C = 25.0


class LumpedPlant:
    """A block and a sensor node per heater, forward Euler at the ISR rate (Marlin's MPC
    defaults for the hotend); good enough to exercise the board."""

    def __init__(self, power_w=(40.0, 200.0), loss_w_per_k=(0.068 * 1.5, 1.6), heat_cap=(16.7, 500.0),
                 sensor_rate_per_s=(0.22, 0.5)):
        self.temp_c = [AMBIENT_C, AMBIENT_C]
        self.sensor_c = [AMBIENT_C, AMBIENT_C]
        self.power_w, self.loss, self.cap = power_w, loss_w_per_k, heat_cap
        self.sensor_rate = sensor_rate_per_s
        self.divider = Divider()
        self.adc_override = {}  # channel -> fixed 10-bit value (sensor fault)
        self.heater_connected = [True, True]

    def sample(self, channel):
        if channel in self.adc_override:
            return self.adc_override[channel]
        return min(1023, int(self.divider.adc_exact(self.sensor_c[channel])))

    def advance(self, board):
        for ch in range(2):
            on = board.pin(ch) if ch < len(board.heaters) else False
            p = self.power_w[ch] if on and self.heater_connected[ch] else 0.0
            self.temp_c[ch] += DT_S * (p - self.loss[ch] * (self.temp_c[ch] - AMBIENT_C)) / self.cap[ch]
            self.sensor_c[ch] += DT_S * self.sensor_rate[ch] * (self.temp_c[ch] - self.sensor_c[ch])


def run(board, plant, seconds):
    for _ in range(int(seconds / DT_S)):
        board.step()
        plant.advance(board)


def test_pid_heats_and_holds_the_hotend():
    plant = LumpedPlant()
    board = MarlinBoard(plant)
    board.set_target(HOTEND_CHANNEL, 210)
    run(board, plant, 240)
    assert not board.halted
    assert abs(board.hotend.temp_q5 / 32 - 210) < 1.5
    assert 0 < board.amount(HOTEND_CHANNEL) < 127


def test_first_reading_after_150_isrs_then_every_160():
    plant = LumpedPlant()
    board = MarlinBoard(plant)
    fresh = []
    for tick in range(1, 3 * TICKS_PER_READING + 1):
        board.isr()
        if board.adc.raw_ready:
            fresh.append(tick)
        board.task()
    assert fresh == [151, 311, 471]  # the 16th StartSampling is ISR 151 (15 samples)


def test_target_is_clamped_to_maxtemp_minus_overshoot():
    board = MarlinBoard(LumpedPlant())
    board.set_target(HOTEND_CHANNEL, 300)
    board.set_target(BED_CHANNEL, 200)
    assert (board.hotend.target_c, board.bed.target_c) == (260, 140)


def test_heater_states_format():
    plant = LumpedPlant()
    board = MarlinBoard(plant)
    board.set_target(HOTEND_CHANNEL, 210)
    run(board, plant, 1.0)
    states = board.heater_states()
    assert states.startswith(" T:")
    assert " /210.00 B:" in states and states.endswith(" @:127 B@:0")


def test_thermal_runaway_when_the_heater_cartridge_falls_out():
    plant = LumpedPlant()
    board = MarlinBoard(plant, has_bed=False)
    board.set_target(HOTEND_CHANNEL, 200)
    run(board, plant, 150)
    assert not board.halted
    plant.heater_connected[0] = False
    run(board, plant, 120)
    assert board.halted
    assert board.console.text == (
        "Error:Thermal Runaway, system stopped! Heater_ID: E0\n\n"
        "echo:THERMAL RUNAWAY\n"
        "Error:Printer halted. kill() called!\n"
    )
    assert board.pin(HOTEND_CHANNEL) is False and board.hotend.target_c == 0
    ticks = board.ticks
    run(board, plant, 5)
    assert board.ticks == ticks and board.pin(HOTEND_CHANNEL) is False  # stays dead until reset


def test_heating_failed_when_the_heater_is_disconnected_from_the_start():
    plant = LumpedPlant()
    plant.heater_connected[0] = False
    board = MarlinBoard(plant, has_bed=False)
    run(board, plant, 1)  # M104 comes after boot, with a real reading
    board.set_target(HOTEND_CHANNEL, 200)
    run(board, plant, 39.8)
    assert not board.halted
    run(board, plant, 2)
    assert board.console.text.startswith("Error:Heating failed, system stopped! Heater_ID: E0\n\n")


def test_without_thermal_protection_neither_runaway_nor_watch_halts_but_maxtemp_does():
    """THERMAL_PROTECTION_HOTENDS off (seed 004's sketch): the two faults above pass unnoticed;
    the heater stays on, as the sketch would leave it. MAXTEMP is not part of that option."""
    for disconnect_after_s in (150, 0):
        plant = LumpedPlant()
        board = MarlinBoard(plant, has_bed=False, thermal_protection=False)
        run(board, plant, 1)
        board.set_target(HOTEND_CHANNEL, 200)
        run(board, plant, disconnect_after_s)
        plant.heater_connected[0] = False
        run(board, plant, 120)
        assert not board.halted and board.console.text == "" and board.pin(HOTEND_CHANNEL) is True
    board.set_target(HOTEND_CHANNEL, 200)
    plant.heater_connected[0] = True
    plant.adc_override[0] = 0  # a shorted thermistor reads as far above MAXTEMP
    run(board, plant, 1)
    assert board.halted and "MAXTEMP" in board.console.text


def test_mintemp_on_open_thermistor_only_when_heating():
    plant = LumpedPlant()
    plant.adc_override[0] = 1023
    board = MarlinBoard(plant, has_bed=False)
    run(board, plant, 1)
    assert not board.halted
    board.set_target(HOTEND_CHANNEL, 200)
    run(board, plant, 0.2)
    assert board.console.text.startswith("Error:MINTEMP triggered, system stopped! Heater_ID: E0\n\n")


def test_maxtemp_on_shorted_bed_thermistor_even_when_idle():
    plant = LumpedPlant()
    plant.adc_override[1] = 0
    board = MarlinBoard(plant)
    run(board, plant, 0.2)
    assert board.console.text == (
        "Error:MAXTEMP triggered, system stopped! Heater_ID: bed\necho:Err: MAXTEMP\nError:Printer halted. kill() called!\n"
    )


class SpyBed(BangBangBed):
    """Records when the board runs the bed controller."""

    def __init__(self):
        super().__init__()
        self.calls_ms = []

    def update(self, temp_q5, target_c, now_ms=0):
        self.calls_ms.append(now_ms)
        return super().update(temp_q5, target_c, now_ms)


def test_bed_bang_bang_acts_every_5_seconds_only():
    plant = LumpedPlant()
    bed = SpyBed()
    board = MarlinBoard(plant, BangBangHotend(), bed)
    board.set_target(BED_CHANNEL, 60)
    run(board, plant, 31)
    gaps = [b - a for a, b in zip(bed.calls_ms, bed.calls_ms[1:])]
    assert len(gaps) == 6
    # the next check is due 5 s after the last one and runs on the first reading after that
    assert all(5000 <= gap < 5000 + 164 for gap in gaps)
    assert board.amount(BED_CHANNEL) == 127


def test_m112_kills():
    board = MarlinBoard(LumpedPlant())
    board.kill_m112()
    assert board.halted
    assert board.console.text == "echo:M112 Shutdown\nError:Printer halted. kill() called!\n"


@pytest.mark.parametrize("controller", [BangBangHotend()])
def test_bang_bang_hotend_switches_every_reading_without_hysteresis(controller):
    plant = LumpedPlant()
    board = MarlinBoard(plant, controller, has_bed=False)
    board.set_target(HOTEND_CHANNEL, 200)
    run(board, plant, 120)
    assert abs(board.hotend.temp_q5 / 32 - 200) < 25
    assert not board.halted


def test_m303_e0_s210_c8_runs_marlins_autotune_and_applies_the_gains():
    plant = LumpedPlant()
    board = MarlinBoard(plant)
    run(board, plant, 1)
    tune = board.start_autotune(HOTEND_CHANNEL, 210, 8, apply=True)
    while board.autotune is not None:
        board.step()
        plant.advance(board)
    assert tune.succeeded and not board.halted
    lines = board.console.lines()
    assert lines[0] == "PID Autotune start"
    assert re.fullmatch(r" T:\d+\.\d\d /0\.00 B:\d+\.\d\d /0\.00 @:127 B@:0", lines[1])
    bias_lines = [line for line in lines if line.startswith(" bias: ")]
    assert len(bias_lines) == 8
    assert sum(" Ku: " in line for line in bias_lines) == 6
    # cycles 1 and 2 leave the line open: the next 2 s report is appended to it
    assert " T:" in bias_lines[0] and " T:" in bias_lines[1]
    assert lines.count(" Classic PID ") == 6
    assert lines[-4] == "PID Autotune finished! Put the last Kp, Ki and Kd constants from below into Configuration.h"
    kp, ki, kd = tune.gains
    assert lines[-3:] == [f"#define DEFAULT_Kp {kp:.2f}", f"#define DEFAULT_Ki {ki:.2f}", f"#define DEFAULT_Kd {kd:.2f}"]
    applied = board.hotend.controller.gains
    assert (applied.kp, applied.ki, applied.kd) == pytest.approx((kp, ki, kd))
    assert board.hotend.target_c == 0
    run(board, plant, 0.5)
    assert board.amount(HOTEND_CHANNEL) == 0  # target 0: the next reading turns it off


def test_m303_refuses_a_target_too_high_without_touching_the_heaters():
    plant = LumpedPlant()
    board = MarlinBoard(plant)
    board.set_target(BED_CHANNEL, 60)
    tune = board.start_autotune(HOTEND_CHANNEL, 261, 5)
    assert tune.done and not tune.succeeded and board.autotune is None
    assert board.console.text == "PID Autotune failed! Temperature too high\n"
    assert board.bed.target_c == 60


def test_m108_cancels_m303_and_turns_the_heater_off():
    plant = LumpedPlant()
    board = MarlinBoard(plant)
    board.start_autotune(HOTEND_CHANNEL, 200, 5)
    run(board, plant, 10)
    assert board.amount(HOTEND_CHANNEL) == 127
    board.cancel_autotune()
    assert board.autotune is None and board.amount(HOTEND_CHANNEL) == 0


def test_bang_bang_firmware_cannot_autotune():
    board = MarlinBoard(LumpedPlant(), BangBangHotend(), BangBangBed())
    assert not board.can_autotune(HOTEND_CHANNEL) and not board.can_autotune(BED_CHANNEL)
    assert MarlinBoard(LumpedPlant()).can_autotune(BED_CHANNEL)
