"""The twin MCU's firmware on a virtual clock (no wall clock, no pty): the command set klippy 0.12
uses, the ADC sums and range check, soft PWM into the plant, max_duration, shutdowns and their
reasons, strict against lenient timing, resets and 32-bit clock wrap."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.klipper_mcu.board import TICK_CLOCKS, TwinBoard
from protocol.klipper_mcu.codec import frame
from protocol.klipper_mcu.dictionary import ADC_OUT_OF_RANGE, COMMAND_REQUEST, TIMER_TOO_CLOSE, pin_number
from protocol.klipper_mcu.mcu import STATS_INTERVAL_S
from tests.klipper_mcu.host import NO_SCENARIO, S, TestHost
from twin.clock import TICK_S
from twin.plants import make_plant
from twin.scenario import parse_scenario

QUERY = ("query_analog_in oid=0 clock={clock} sample_ticks=16000 sample_count=8 rest_ticks=4800000 min_value={low}"
         " max_value=8000 range_check_count=4")
ADC_AT_25C = 978  # floor(1024 R / (R + 4700)) for the EPCOS 100K at 25 C (R = 100 kOhm)


def reason_id(host: TestHost, text: str) -> int:
    return host.dictionary.static_string_ids[text]


def test_identify_serves_the_dictionary_in_chunks():
    host = TestHost()
    data = b""
    while True:
        host.send(0, f"identify offset={len(data)} count=40")
        chunk = host.named("identify_response")[-1]
        assert chunk["offset"] == len(data)
        if not chunk["data"]:
            break
        data += chunk["data"]
    assert data == host.dictionary.data()
    assert host.acks == len(host.named("identify_response"))  # every good block is acked


def test_wrong_sequence_gets_a_nak_with_the_expected_one():
    host = TestHost()
    host.raw(0, frame(5, b""))
    assert host.acks == 1
    host.send(0, "get_clock")  # sequence 0: accepted
    assert host.named("clock") == [{"clock": 0}]


def test_configuration_and_adc_reports():
    host = TestHost()
    host.send(0, "get_config")
    assert host.named("config")[-1]["is_config"] == 0
    host.configure()
    host.send(S // 2, "get_config")
    assert host.named("config")[-1] == {"is_config": 1, "crc": 1234, "is_shutdown": 0, "move_count": 1024}
    host.send(S // 2, QUERY.format(clock=S, low=100))
    host.run(3 * S)
    reports = host.named("analog_in_state")
    # sample groups at 1.0, 1.3, ... s; each reported after its 8th sample, next_clock one rest on
    assert [r["next_clock"] for r in reports] == [S + k * 4_800_000 for k in range(1, 8)]
    assert {r["value"] for r in reports} == {8 * ADC_AT_25C}


def test_soft_pwm_drives_the_plant_exactly():
    host = TestHost()
    host.configure()
    start = S + 123  # inside a plant tick: that tick gets its on-part only
    host.send(S // 2, f"queue_digital_out oid=1 clock={start} on_ticks={S // 20}",  # 50 % from 1 s
              f"queue_digital_out oid=1 clock={3 * S} on_ticks=0")
    host.run(4 * S)
    fractions = host.board.heaters["hotend"].pin.fractions(0, 4 * S // TICK_CLOCKS)
    tick = start // TICK_CLOCKS
    assert fractions[tick - 1] == 0.0 and fractions[tick] == (TICK_CLOCKS - start % TICK_CLOCKS) / TICK_CLOCKS
    on_clocks = fractions.sum() * TICK_CLOCKS
    assert on_clocks == pytest.approx(20 * (S // 20), abs=1)  # 20 cycles of 0.1 s, half on each
    # the board's plant is the twin's own plant run on those fractions
    host.board.advance(4 * S // TICK_CLOCKS)
    plant = make_plant("hotend_stock")
    plant.advance(fractions)
    assert host.board.temps_c("hotend") == pytest.approx(tuple(plant.temps_c()), rel=1e-12)  # runs split elsewhere


@pytest.mark.parametrize("strict", [True, False])
def test_a_late_event_is_timer_too_close_only_when_strict(strict):
    host = TestHost(strict=strict)
    host.configure()
    host.send(2 * S, f"queue_digital_out oid=1 clock={S} on_ticks={S // 10}")
    if strict:
        assert host.named("shutdown") == [{"clock": 2 * S, "static_string_id": reason_id(host, TIMER_TOO_CLOSE)}]
    else:
        assert not host.named("shutdown") and host.mcu.lateness.late_events == 1
        assert host.mcu.lateness.max_late_clocks == S
        host.run(2 * S + TICK_CLOCKS)
        # applied as early as the plants allow: they had not run, so from its own clock
        assert host.board.heaters["hotend"].pin.fractions(S // TICK_CLOCKS + 1, 1)[0] == 1.0


@pytest.mark.parametrize("strict", [True, False])
def test_a_heater_left_on_goes_off_at_max_duration_in_either_mode(strict):
    host = TestHost(strict=strict)
    host.configure(max_duration_s=5.0)
    host.send(0, f"queue_digital_out oid=1 clock={S} on_ticks={S // 10}")  # full on from 1 s, then nothing
    host.run(6 * S + host.mcu.grace_clocks + 1)
    missed = reason_id(host, "Missed scheduling of next digital out event")
    shut_at = 6 * S if strict else 6 * S + host.mcu.grace_clocks  # lenient waits for a late event first
    assert host.named("shutdown") == [{"clock": shut_at, "static_string_id": missed}]
    pin = host.board.heaters["hotend"].pin
    assert pin.fractions(6 * S // TICK_CLOCKS - 10, 10).min() == 1.0  # on until max_duration ...
    assert pin.fractions(6 * S // TICK_CLOCKS + 1, 100).max() == 0.0  # ... and off from there in either mode
    assert host.mcu.lateness.forgiven_deadlines == 0


def test_lenient_forgives_an_event_that_comes_late_after_max_duration():
    host = TestHost()
    host.configure(max_duration_s=5.0)
    host.send(0, f"queue_digital_out oid=1 clock={S} on_ticks={S // 10}")
    late = 6 * S + host.mcu.grace_clocks // 2  # within the grace; it was meant for 5.9 s
    host.send(late, f"queue_digital_out oid=1 clock={59 * S // 10} on_ticks={S // 10}")
    host.run(late + host.mcu.grace_clocks)
    assert not host.named("shutdown")
    lateness = host.mcu.lateness
    assert (lateness.forgiven_deadlines, lateness.max_overdue_clocks, lateness.late_events) == (1, late - 6 * S, 1)
    pin = host.board.heaters["hotend"].pin
    assert pin.fractions(late // TICK_CLOCKS + 1, 10).min() == 1.0  # on again
    assert "1 max_duration misses forgiven" in lateness.line()


def test_an_event_beyond_max_duration_shuts_down_in_either_mode():
    host = TestHost()
    host.configure(max_duration_s=5.0)
    host.send(0, f"queue_digital_out oid=1 clock={S} on_ticks={S // 10}",
              f"queue_digital_out oid=1 clock={7 * S} on_ticks=0")
    host.run(2 * S)
    assert [s["static_string_id"] for s in host.named("shutdown")] == [
        reason_id(host, "Scheduled digital out event will exceed max_duration")]


def test_emergency_stop_and_what_a_shut_down_mcu_answers():
    host = TestHost()
    host.configure()
    host.send(S // 2, QUERY.format(clock=S, low=100), f"queue_digital_out oid=1 clock={S} on_ticks={S // 10}")
    host.send(2 * S, "emergency_stop")
    stop_id = reason_id(host, COMMAND_REQUEST)
    assert host.named("shutdown") == [{"clock": 2 * S, "static_string_id": stop_id}]
    assert host.board.heaters["hotend"].pin.fractions(2 * S // TICK_CLOCKS + 1, 5).max() == 0.0  # heater off
    host.send(2 * S, f"queue_digital_out oid=1 clock={3 * S} on_ticks=1", "get_config")
    assert host.named("is_shutdown") == [{"static_string_id": stop_id}]
    assert host.named("config")[-1]["is_shutdown"] == 1
    reports_before = len(host.named("analog_in_state"))
    host.run(4 * S)
    assert len(host.named("analog_in_state")) > reports_before  # the ADC keeps reporting
    host.send(4 * S, "clear_shutdown", "get_config")
    assert host.named("config")[-1]["is_shutdown"] == 0


def test_open_thermistor_is_adc_out_of_range_after_four_reports():
    open_at_0 = parse_scenario('name = "t"\nduration_s = 100\n[[fault]]\nat_s = 0\nheater = "hotend"\n'
                               'kind = "thermistor_open"\n', "t")
    host = TestHost(TwinBoard(open_at_0))
    host.configure()
    host.send(S // 2, QUERY.format(clock=S, low=100))
    host.run(5 * S)
    reports = host.named("analog_in_state")
    shutdown = host.named("shutdown")
    assert [s["static_string_id"] for s in shutdown] == [reason_id(host, ADC_OUT_OF_RANGE)]
    # three reports of 8 x 1023, the fourth group shuts down instead of reporting; sampling goes on after
    assert reports[0]["value"] == 8 * 1023 and len(reports) >= 4
    assert reports[3]["next_clock"] == S + 5 * 4_800_000
    assert shutdown[0]["clock"] == S + 3 * 4_800_000 + 7 * 16000


def test_reset_reboots_the_mcu_but_not_the_world():
    host = TestHost()
    host.configure()
    host.send(10 * S, "reset")
    assert host.mcu.boot_clock == 10 * S
    host.sequence = 0  # a new session on the new boot
    host.send(10 * S + 1000, "get_uptime", "get_config")
    assert host.named("uptime")[-1] == {"high": 0, "clock": 1000}
    assert host.named("config")[-1]["is_config"] == 0


def test_clock_wraps_at_32_bits():
    host = TestHost()
    host.configure()
    start = 2**32 + 5 * S
    host.run(start)
    host.send(start, QUERY.format(clock=(start + S) & 0xFFFFFFFF, low=100))
    host.run(start + 2 * S)
    first = host.named("analog_in_state")[0]
    assert first["next_clock"] == (start + S + 4_800_000) & 0xFFFFFFFF
    assert len(host.named("stats")) == (start + 2 * S) // round(STATS_INTERVAL_S * S)


def test_a_scenario_fault_cuts_the_heater():
    cut = parse_scenario('name = "t"\nduration_s = 100\n[[fault]]\nat_s = 2.0\nheater = "hotend"\n'
                         'kind = "heater_disconnected"\n', "t")
    board = TwinBoard(cut)
    host = TestHost(board)
    host.configure()
    host.send(0, f"queue_digital_out oid=1 clock={S} on_ticks={S // 10}")
    host.send(3 * S, f"queue_digital_out oid=1 clock={4 * S} on_ticks={S // 10}")
    end = 6 * S // TICK_CLOCKS
    board.advance(end)
    on_tick, fault_tick = S // TICK_CLOCKS, round(2.0 / TICK_S)  # the fault acts from the tick nearest 2.0 s
    u = np.zeros(end)
    u[on_tick] = ((on_tick + 1) * TICK_CLOCKS - S) / TICK_CLOCKS  # on from clock S within its tick
    u[on_tick + 1:fault_tick] = 1.0
    ref = make_plant("hotend_stock")
    ref.advance(u)
    assert board.temps_c("hotend") == pytest.approx(tuple(ref.temps_c()), rel=1e-12)  # runs split elsewhere


def test_unwired_adc_pin_reads_open_and_a_non_adc_pin_is_refused():
    host = TestHost(TwinBoard(NO_SCENARIO))
    host.send(0, "allocate_oids count=2", f"config_analog_in oid=0 pin={pin_number('PF3')}")
    assert host.board.adc("PF3", 0) == 1023
    host.send(0, f"config_analog_in oid=1 pin={pin_number('PB4')}")
    assert [s["static_string_id"] for s in host.named("shutdown")] == [reason_id(host, "Not a valid ADC pin")]


def test_hardware_pwm_sets_the_fan_and_keeps_its_max_duration():
    host = TestHost(strict=True)
    fan = pin_number("PH6")
    host.send(0, "allocate_oids count=1",
              f"config_pwm_out oid=0 pin={fan} cycle_ticks=1600 value=0 default_value=0 max_duration={2 * S}",
              "finalize_config crc=1", f"queue_pwm_out oid=0 clock={S} value=128")
    host.run(S + TICK_CLOCKS)
    host.board.advance(S // TICK_CLOCKS + 2)
    assert host.board.heaters["hotend"].plant.fan == pytest.approx(128 / 255)
    host.run(4 * S)  # nothing after the 128 within 2 s
    assert [s["static_string_id"] for s in host.named("shutdown")] == [
        reason_id(host, "Missed scheduling of next hard pwm event")]
    assert host.board.fan.duty() == 0.0  # back to its default value
