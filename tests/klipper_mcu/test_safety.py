"""A host that dies: kill -9 the registry's klippy with a heater at full power, and the twin MCU
switches the heater off at its max_duration and shuts down with Klipper's message, as a real MCU
does (before, the lenient MCU heated on until the ADC range check tripped 80 s later).

The bed is the heater here: its sensor follows its heat closely, so the reading can show what
the MCU did. A hotend's sensor lags its block by seconds: after a real MCU's 5 s it still rises
12-41 C on the twin's hotend plants (test_mcu.py checks the pin itself on a virtual clock)."""

from __future__ import annotations

import os
import select
import time

import pytest

from firmware_port.thermistor import KLIPPER_SENSORS
from protocol.klipper_mcu.codec import BlockReader, parse_messages
from protocol.klipper_mcu.dictionary import DEFAULT_SENSOR, MISSED_DIGITAL_OUT, build_dictionary
from twin.klipper_twin import calc_temp

pytestmark = pytest.mark.slow

BED = "heater_bed"
SAMPLES = 8  # klippy's sample_count per report
REPORT_S = 0.3  # klippy's report time
WATCH_S = 60.0  # MCU seconds watched after the kill: max_duration (5 s), the lenient grace, the bed's lag
MAX_RISE_C = 10.0
WAIT_S = 300.0  # hang guard of each wait (wall)


def bed_c(api) -> float:
    return api.query(BED)[BED]["temperature"]


def reports_after_the_kill(link: str, seconds: float) -> list[float]:
    """The hottest sensor of each report the MCU sends over ``seconds`` of its clock, read from its
    port as a new host that sends nothing."""
    responses = {fmt.msg_id: fmt for fmt in build_dictionary("reader").responses.values()}
    reader = BlockReader()
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    temps: dict[int, list[float]] = {}
    deadline = time.monotonic() + WAIT_S
    try:
        while min((len(t) for t in temps.values()), default=0) * REPORT_S < seconds:
            assert time.monotonic() < deadline, "the MCU stopped reporting"
            if not select.select([fd], [], [], 1.0)[0]:
                continue
            for block in reader.feed(os.read(fd, 4096)):
                for fmt, params in parse_messages(block.payload if block else b"", responses):
                    if fmt.name == "analog_in_state":
                        ratio = params["value"] / (SAMPLES * 1023)
                        temps.setdefault(params["oid"], []).append(
                            calc_temp(KLIPPER_SENSORS[DEFAULT_SENSOR], 4700.0, ratio))
    finally:
        os.close(fd)
    return [max(group) for group in zip(*temps.values())]


def test_a_dead_host_leaves_no_heater_on(klipper):
    session = klipper()
    api = session.api
    api.gcode(f"SET_HEATER_TEMPERATURE HEATER={BED} TARGET=110")  # full power for minutes
    deadline = time.monotonic() + WAIT_S
    while (at_kill_c := bed_c(api)) < 40.0:
        assert time.monotonic() < deadline, f"the bed never reached 40 C ({at_kill_c})"
        time.sleep(0.05)
    session.kill_klippy()
    after = reports_after_the_kill(str(session.link), WATCH_S)
    assert max(after) < at_kill_c + MAX_RISE_C, (at_kill_c, after)
    assert after[-1] < max(after)  # cooling: the heater is off
    assert "MCU shutdown at clock" in session.mcu_stderr() and MISSED_DIGITAL_OUT in session.mcu_stderr()
