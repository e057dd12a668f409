"""The twin MCU as the chip a printer.cfg's [mcu] is: an STM32's 16 pins a port, 72 MHz clock, 12-bit ADC and
1 << 15 hardware PWM as klippy reads them from the dictionary, and the firmware's timing in that chip's clocks
(max_duration, stats, the plant tick); the AVR's stay as they were."""

from __future__ import annotations

import json
import zlib

import numpy as np
import pytest

from protocol.klipper_mcu.board import TICK_CLOCKS, TwinBoard, Wiring, tick_clocks
from protocol.klipper_mcu.dictionary import BOARD_CHIP, CHIPS, Chip, build_dictionary
from protocol.klipper_mcu.mcu import STATS_INTERVAL_S
from protocol.klipper_mcu.user_config import read_user_config
from tests.klipper_mcu.host import NO_SCENARIO, TestHost
from tests.klipper_mcu.test_user_config import ENDER3, write
from twin.clock import TICK_S

STM32F103 = CHIPS["stm32f103"]
MHZ_72 = 72_000_000


def stm32_host(strict: bool = True) -> TestHost:
    """An stm32f103 board with the Ender 3 V2's hotend wiring: heater PA1, thermistor PC5."""
    board = TwinBoard(NO_SCENARIO, ("hotend",), wirings=(Wiring("hotend", "PA1", "PC5", "extruder", 250.0),),
                      fan_pin=None, chip=STM32F103)
    return TestHost(board, strict=strict, dictionary=build_dictionary("test", STM32F103))


def configure(host: TestHost, max_duration_s: float = 5.0) -> None:
    chip, s = host.dictionary.chip, host.dictionary.chip.clock_freq
    host.send(0, "allocate_oids count=2", f"config_analog_in oid=0 pin={chip.pin_number('PC5')}",
              f"config_digital_out oid=1 pin={chip.pin_number('PA1')} value=0 default_value=0 "
              f"max_duration={int(max_duration_s * s)}",
              f"set_digital_out_pwm_cycle oid=1 cycle_ticks={s // 10}", "finalize_config crc=1")


def test_the_stm32_dictionary_is_what_klippy_reads_from_a_real_one():
    doc = json.loads(zlib.decompress(build_dictionary("test", STM32F103).data()))
    assert doc["config"]["CLOCK_FREQ"] == MHZ_72 and doc["config"]["MCU"] == "stm32f103xe"
    assert (doc["config"]["ADC_MAX"], doc["config"]["PWM_MAX"]) == (4095, 1 << 15)
    assert doc["enumerations"]["pin"]["PB0"] == [16, 16] and doc["enumerations"]["pin"]["PG0"] == [96, 16]
    avr = json.loads(zlib.decompress(build_dictionary("test").data()))
    assert (avr["config"]["CLOCK_FREQ"], avr["config"]["ADC_MAX"], avr["enumerations"]["pin"]["PB0"]) == (
        16_000_000, 1023, [8, 8])


def test_pins_sixteen_a_port():
    assert (STM32F103.pin_number("PA15"), STM32F103.pin_number("PB4"), STM32F103.pin_name(20)) == (15, 20, "PB4")
    assert STM32F103.has_pin(STM32F103.pin_number("PG15")) and not STM32F103.has_pin(7 * 16)
    for bad in ("PA16", "PH0", "PA01", "PA"):
        with pytest.raises(ValueError, match=f"no pin '{bad}' on the stm32f103"):
            STM32F103.pin_number(bad)
    with pytest.raises(ValueError, match="no pin 'PA8' on the atmega2560"):
        CHIPS["atmega2560"].pin_number("PA8")


def test_every_chip_has_a_whole_number_of_clocks_per_plant_tick():
    assert TICK_CLOCKS == 16384 and tick_clocks(STM32F103) == 73728
    for chip in CHIPS.values():
        assert tick_clocks(chip) == TICK_S * chip.clock_freq
    with pytest.raises(ValueError, match="no whole number of clocks per plant tick"):
        tick_clocks(Chip("odd", "AB", (), clock_freq=1_000_001))


def test_a_32_bit_config_without_a_chip_comment_is_the_stm32f103(tmp_path):
    text = ENDER3.replace("the firmware should be compiled for the AVR atmega1284p.", "the firmware should fit.")
    config = read_user_config(write(tmp_path, text.replace("pin: PB4", "pin: PA15")))  # the fan: no AVR has PA15
    assert config.chip is STM32F103 and config.fan_pin == "PA15"
    assert read_user_config(write(tmp_path, text), "stm32f407").chip.mcu_constant == "stm32f407xx"
    on_adc3 = text.replace("pin: PB4", "pin: PA15").replace("sensor_pin: PA7", "sensor_pin: PF4")
    assert read_user_config(write(tmp_path, on_adc3)).chip.name == "stm32f407"  # PF4: ADC3, not on an stm32f103


def test_the_stm32_adc_reads_twelve_bits_of_the_same_divider():
    """At 25 C the EPCOS 100K on a 4.7 k pull-up is floor(4096 R / (R + Rp)) = 3912 (the AVR's 978, x 4 within
    the quantisation); the sum of 8 samples is what klippy divides by 8 x ADC_MAX (4095)."""
    host = stm32_host()
    configure(host)
    s = MHZ_72
    host.send(0, f"query_analog_in oid=0 clock={s} sample_ticks={s // 1000} sample_count=8 rest_ticks={3 * s // 10}"
                 " min_value=0 max_value=32760 range_check_count=4")
    host.run(2 * s)
    value = host.named("analog_in_state")[0]["value"]
    assert value == 8 * 3912
    avr = TwinBoard(NO_SCENARIO).adc("PK5", 0)
    assert avr == 978 and abs(value / 8 / 4 - avr) < 1


@pytest.mark.parametrize("strict", [True, False])
def test_max_duration_and_stats_run_on_the_chip_clock(strict):
    host = stm32_host(strict)
    configure(host, max_duration_s=5.0)
    s = MHZ_72
    host.send(0, f"queue_digital_out oid=1 clock={s} on_ticks={s // 10}")  # full on from 1 s, then nothing
    assert host.mcu.grace_clocks == s  # lenient: one second of this chip's clock
    host.run(6 * s + host.mcu.grace_clocks + 1)
    shut_at = 6 * s if strict else 6 * s + host.mcu.grace_clocks
    assert [r["clock"] for r in host.named("shutdown")] == [shut_at]
    pin = host.board.heaters["hotend"].pin
    ticks = tick_clocks(STM32F103)
    assert pin.fractions(6 * s // ticks - 10, 10).min() == 1.0 and pin.fractions(6 * s // ticks + 1, 100).max() == 0.0
    assert len(host.named("stats")) == (6 * s + host.mcu.grace_clocks) // round(STATS_INTERVAL_S * s)


def test_the_heater_warms_the_same_plant_whatever_the_clock():
    """Half power for 20 s (25 C to 57 C): the hotend's temperature does not depend on the chip's clock (same plant ticks)."""
    temps = []
    for host, chip in ((stm32_host(), STM32F103), (TestHost(), BOARD_CHIP)):
        s = chip.clock_freq
        if chip is STM32F103:
            configure(host)
        else:
            host.configure()
        for k in range(200):  # a new half-on cycle every 0.1 s, within max_duration
            host.send(k * s // 10, f"queue_digital_out oid=1 clock={s + k * s // 10} on_ticks={s // 20}")
        host.run(21 * s)
        host.board.advance(round(21 / TICK_S))
        temps.append(host.board.temps_c("hotend")[0])
    assert temps[0] > 45 and np.isclose(temps[0], temps[1], atol=1e-6), temps


@pytest.mark.parametrize("name", ["stm32f103", "stm32f070", "stm32f407", "stm32g0b1", "stm32h743"])
def test_the_chips_own_temperature_reads_back_as_klippys_temperature_mcu_computes_it(name):
    """debug_read of the calibration half-words and a conversion of ADC_TEMPERATURE (pin 0xfe), put through
    klippy/extras/temperature_mcu.py's laws (written out here, per family), give the twin chip's temperature
    (ambient + 10 C) within a few LSB of its 12-bit ADC (0.3-0.8 C)."""
    chip = CHIPS[name]
    host = TestHost(TwinBoard(NO_SCENARIO, (), wirings=(), fan_pin=None, chip=chip),
                    dictionary=build_dictionary("test", chip))
    s = chip.clock_freq

    def read16(addr: int) -> int:
        host.send(0, f"debug_read order=1 addr={addr}")
        return host.named("debug_result")[-1]["val"]

    host.send(0, "allocate_oids count=1", "config_analog_in oid=0 pin=254", "finalize_config crc=1")
    host.send(0, f"query_analog_in oid=0 clock={s} sample_ticks={s // 1000} sample_count=8 rest_ticks={s // 3}"
                 " min_value=0 max_value=32760 range_check_count=0")
    host.run(2 * s)
    frac = host.named("analog_in_state")[0]["value"] / (8 * 4095)
    if name == "stm32f103":
        slope, at_c, cal = 3.3 / -0.0043, 25.0, 1.43 / 3.3
    elif name == "stm32f070":
        slope, at_c, cal = 3.3 / -0.0043, 30.0, read16(0x1FFFF7B8) / 4095
    elif name == "stm32f407":
        cal, hot = read16(0x1FFF7A2C) / 4095, read16(0x1FFF7A2E) / 4095
        slope, at_c = (110 - 30) / (hot - cal), 30.0
    elif name == "stm32g0b1":
        cal, hot = (read16(a) * 3.0 / (3.3 * 4095) for a in (0x1FFF75A8, 0x1FFF75CA))
        slope, at_c = (130 - 30) / (hot - cal), 30.0
    else:
        cal, hot = read16(0x1FF1E820) / 65535, read16(0x1FF1E840) / 65535
        slope, at_c = (110 - 30) / (hot - cal), 30.0
    temp_c = at_c - cal * slope + frac * slope
    assert abs(temp_c - (NO_SCENARIO.ambient_c + 10.0)) < 1.0, temp_c
    assert not host.named("shutdown")


def test_an_avr_has_no_temperature_channel():
    host = TestHost(dictionary=build_dictionary("test", CHIPS["atmega2560"]))
    host.send(0, "allocate_oids count=1", "config_analog_in oid=0 pin=254")
    assert host.named("shutdown")  # "Not a valid ADC pin", as src/avr/adc.c answers
