"""M109/M190's wait loop as Marlin 2.1 writes it (temperature.cpp wait_for_hotend / wait_for_bed)."""

from __future__ import annotations

from protocol.build import build_printer


def test_a_target_of_minus_one_is_not_a_change_so_m109_s_minus_1_waits_until_m108():
    """``float target_temp = -1.0``: M109 S-1 never sees its target change, so S does not end it as
    a cooling wait; the residency cannot start 26 C away, and only M108 breaks the wait."""
    printer = build_printer(with_bed=False)
    printer.take_output()
    printer.receive(b"M109 S-1\n")
    printer.run_for(60)
    assert printer.executing
    printer.receive(b"M108\n")
    printer.run_until_idle(10)
    assert not printer.executing
    assert printer.take_output().decode().splitlines()[-2:] == ["ok", "ok"]
