"""The twin MCU's steppers, endstops and trsyncs on a virtual clock (protocol/klipper_mcu/motion.py, axes.py):
steps where src/stepper.c puts them, homing that triggers where the carriage reaches its switch and stops the
steppers there, trsync reports and timeouts as src/trsync.c gives them."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from protocol.klipper_mcu import dictionary as d
from protocol.klipper_mcu.mcu import PRINTER_FAMILIES
from protocol.klipper_mcu.axes import Move
from protocol.klipper_mcu.board import TwinBoard
from protocol.klipper_mcu.dictionary import build_dictionary
from protocol.klipper_mcu.user_config import read_user_config
from tests.klipper_mcu.host import NO_SCENARIO, S, TestHost
from tests.klipper_mcu.test_user_config import ENDER3

REPORT_TICKS = S // 100  # klippy: 0.4 of its 25 ms trsync timeout is 10 ms; the twin's tests take 10 ms too
ENDSTOP_HIT, COMMS_TIMEOUT = 1, 2  # klippy/mcu.py MCU_trsync reasons


@given(st.integers(1, 10**6), st.integers(1, 3000), st.integers(-200, 200), st.integers(0, 10**7))
def test_steps_by_a_clock_are_the_steps_stepper_c_would_have_made(interval, count, add, clock):
    move = Move(1000, interval, count, add, 1)
    times = [move.step_clock(k) for k in range(1, count + 1)]
    if any(b < a for a, b in zip(times, times[1:])):
        return  # a negative add past zero interval: klippy never sends one
    assert move.steps_by(clock) == sum(t <= clock for t in times)


def ender3_host(tmp_path, *, strict: bool = False) -> tuple[TestHost, object]:
    path = tmp_path / "printer.cfg"
    path.write_text(ENDER3)
    config = read_user_config(path)
    board = TwinBoard.for_config(config, NO_SCENARIO)
    host = TestHost(board, strict=strict, dictionary=build_dictionary("test", config.chip, families=PRINTER_FAMILIES))
    return host, config


def configure_x(host: TestHost, chip) -> None:
    """klippy's stepper_x on the Ender 3: oid 0 its stepper (PD7, dir PC5), 1 its endstop (PC2), 2 the trsync."""
    step, direction, endstop = (chip.pin_number(p) for p in ("PD7", "PC5", "PC2"))
    host.send(0, "allocate_oids count=3",
              f"config_stepper oid=0 step_pin={step} dir_pin={direction} invert_step=0 step_pulse_ticks=32",
              f"config_endstop oid=1 pin={endstop} pull_up=1", "config_trsync oid=2", "finalize_config crc=1")


def home_x(host: TestHost, start: int, *, steps: int = 12000, interval: int = 400) -> None:
    """A homing move towards x=0 from mid-travel (x's dir pin is inverted: MCU dir 1 is klippy's negative)."""
    host.send(start, f"trsync_start oid=2 report_clock={start} report_ticks={REPORT_TICKS} expire_reason={COMMS_TIMEOUT}",
              "stepper_stop_on_trigger oid=0 trsync_oid=2",
              f"trsync_set_timeout oid=2 clock={(start + 100 * S) & 0xFFFFFFFF}",
              f"endstop_home oid=1 clock={start} sample_ticks=240 sample_count=4 rest_ticks=400 pin_value=1 "
              f"trsync_oid=2 trigger_reason={ENDSTOP_HIT}",
              f"reset_step_clock oid=0 clock={start}", "set_next_step_dir oid=0 dir=1",
              f"queue_step oid=0 interval={interval} count={steps} add=0")


def test_homing_triggers_where_the_carriage_reaches_its_switch(tmp_path):
    host, config = ender3_host(tmp_path)
    configure_x(host, config.chip)
    home_x(host, S)
    host.run(S + 12000 * 400 + S)
    # from 117.5 mm at 0.0125 mm per step: the switch at 0 closes on step 9400, at S + 9400 * 400; the first
    # sample at or after it (every 400 clocks from S) sees it, and three more 240 clocks apart confirm it
    hit = S + 9400 * 400 + 3 * 240
    states = host.named("trsync_state")
    assert states[-1] == {"oid": 2, "can_trigger": 0, "trigger_reason": ENDSTOP_HIT, "clock": hit}
    assert all(s["can_trigger"] for s in states[:-1]) and len(states) == (hit - S) // REPORT_TICKS + 2
    host.send(hit + S, "stepper_get_position oid=0", "endstop_query_state oid=1")
    assert host.named("stepper_position") == [{"oid": 0, "pos": 9401}]  # the steps up to the last sample
    assert host.named("endstop_state") == [{"oid": 1, "homing": 0, "next_clock": S + 9400 * 400 + 400, "pin_value": 1}]
    assert not host.named("shutdown")


def test_a_stopped_stepper_drops_moves_until_its_clock_is_reset(tmp_path):
    host, config = ender3_host(tmp_path)
    configure_x(host, config.chip)
    home_x(host, S)
    after = 2 * S + 12000 * 400
    host.send(after, "set_next_step_dir oid=0 dir=0", "queue_step oid=0 interval=400 count=100 add=0",
              "stepper_get_position oid=0")
    host.send(after + S, f"reset_step_clock oid=0 clock={after + S}", "queue_step oid=0 interval=400 count=100 add=0")
    host.send(after + 2 * S, "stepper_get_position oid=0")
    assert [p["pos"] for p in host.named("stepper_position")] == [9401, 9301]


def test_a_trsync_the_host_stops_renewing_times_out(tmp_path):
    host, config = ender3_host(tmp_path, strict=True)
    configure_x(host, config.chip)
    host.send(S, f"trsync_start oid=2 report_clock={S} report_ticks={REPORT_TICKS} expire_reason={COMMS_TIMEOUT}",
              "stepper_stop_on_trigger oid=0 trsync_oid=2", f"trsync_set_timeout oid=2 clock={S + S // 40}",
              f"reset_step_clock oid=0 clock={S}", "set_next_step_dir oid=0 dir=1",
              "queue_step oid=0 interval=400 count=12000 add=0")
    host.run(3 * S)
    assert host.named("trsync_state")[-1] == {"oid": 2, "can_trigger": 0, "trigger_reason": COMMS_TIMEOUT,
                                              "clock": S + S // 40}
    host.send(3 * S, "stepper_get_position oid=0")
    assert host.named("stepper_position") == [{"oid": 0, "pos": (S // 40) // 400}]  # stopped at the timeout


def test_lenient_mode_forgives_a_renewal_within_the_grace(tmp_path):
    host, config = ender3_host(tmp_path)
    configure_x(host, config.chip)
    host.send(S, f"trsync_start oid=2 report_clock={S} report_ticks={REPORT_TICKS} expire_reason={COMMS_TIMEOUT}",
              f"trsync_set_timeout oid=2 clock={S + S // 40}")
    late = S + S // 40 + host.mcu.grace_clocks // 2
    host.send(late, f"trsync_set_timeout oid=2 clock={late + S // 40}")
    host.run(late + S // 80)
    assert all(s["can_trigger"] for s in host.named("trsync_state"))
    assert host.mcu.lateness.forgiven_deadlines == 1
    host.run(late + S // 40 + host.mcu.grace_clocks + 1)  # no renewal at all: it times out after the grace
    assert host.named("trsync_state")[-1]["trigger_reason"] == COMMS_TIMEOUT


def test_pins_the_chip_lacks_are_klippers_shutdowns(tmp_path):
    host, config = ender3_host(tmp_path)
    host.send(0, "allocate_oids count=2", f"config_endstop oid=0 pin={8 * 4} pull_up=1")  # PE0: no port E
    assert host.mcu.shutdown_reason == d.NOT_INPUT_PIN


def test_steps_after_the_clock_passes_half_its_32_bits(tmp_path):
    """klippy resets a stopped stepper's clock to 0 and then sends the first step as an interval from it, modulo
    2**32: 134 s after boot at 16 MHz that interval is past 2**31, and the step is still now, not 268 s away."""
    host, config = ender3_host(tmp_path)
    configure_x(host, config.chip)
    start = 3 << 30
    host.send(start, f"trsync_start oid=2 report_clock={start} report_ticks={REPORT_TICKS} expire_reason={COMMS_TIMEOUT}",
              "stepper_stop_on_trigger oid=0 trsync_oid=2", f"trsync_set_timeout oid=2 clock={(start + 100 * S) & 0xFFFFFFFF}",
              f"endstop_home oid=1 clock={start} sample_ticks=240 sample_count=4 rest_ticks=400 pin_value=1 "
              f"trsync_oid=2 trigger_reason={ENDSTOP_HIT}",
              "reset_step_clock oid=0 clock=0", "set_next_step_dir oid=0 dir=1",
              f"queue_step oid=0 interval={start + 400} count=1 add=0", "queue_step oid=0 interval=400 count=11999 add=0")
    host.run(start + 12000 * 400 + S)
    assert host.named("trsync_state")[-1] == {"oid": 2, "can_trigger": 0, "trigger_reason": ENDSTOP_HIT,
                                              "clock": start + 9400 * 400 + 3 * 240}
