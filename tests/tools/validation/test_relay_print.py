"""tools/validation/relay_print.py: every Ku and gain line of the M303 captures follows from its own printed
d/min/max/Tu through Marlin's float32 formulas, within the print rounding; and a wrong number does not."""

import dataclasses

import pytest

from tools.logs import M303Cycle, load_log
from tools.validation.relay_print import check_cycle, check_log

ENDER = M303Cycle(6, "T", 87, 87, 206.02, 214.37, 26.50, 10.58, 15.90, 3.01, 21.02, "Classic PID")  # its first line


@pytest.mark.each_hardware_log("m303_*.txt")
def test_every_printed_gain_is_reproduced(hardware_log):
    values = check_log(load_log(hardware_log))
    assert [v for v in values if not v.reproduced] == []


def test_the_captures_hold_the_gain_lines_counted(hardware_logs):
    """README D: 67 printed numbers (Ku on 19 lines, Kp/Ki/Kd on 16 of them): none silently skipped."""
    values = [v for path in sorted(hardware_logs.glob("m303_*.txt")) for v in check_log(load_log(path))]
    assert len(values) == 67 and sum(v.name == "Ku" for v in values) == 19


@pytest.mark.parametrize("field, delta", [("ku", 0.1), ("kp", 0.02), ("ki", 0.02), ("kd", 0.05), ("d", 1),
                                          ("tu_s", 0.05), ("max_c", 0.05)])
def test_a_changed_number_is_not_reproduced(field, delta):
    assert all(v.reproduced for v in check_cycle(ENDER))
    changed = dataclasses.replace(ENDER, **{field: getattr(ENDER, field) + delta})
    assert not all(v.reproduced for v in check_cycle(changed))


def test_the_rule_matters():
    """The same numbers under "No overshoot" (Kp = 0.2 Ku) are not what this Classic PID line printed."""
    assert not all(v.reproduced for v in check_cycle(dataclasses.replace(ENDER, rule="No overshoot")))


def test_repetier_takes_the_full_swing(hardware_logs):
    """Repetier's Ku is half Marlin's for the same d, min, max: read as Marlin, its Ku is not reproduced."""
    (cycle,) = [c for c in load_log(hardware_logs / "m303_hotend_repetier_davinci356.txt").cycles if c.ku]
    assert all(v.reproduced for v in check_cycle(cycle, full_swing=True))
    assert not check_cycle(cycle, full_swing=False)[0].reproduced
