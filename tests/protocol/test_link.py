"""The 115200-baud wire in virtual time: what a host that pipelines its lines sees."""

from __future__ import annotations

import pytest

from protocol.build import build_printer
from protocol.lines import with_checksum
from protocol.link import BYTE_TICKS, SerialLink
from twin.clock import TICK_S


def test_a_write_to_an_idle_link_has_its_first_line_at_once_and_the_rest_at_the_byte_rate():
    link = SerialLink()
    link.send(b"M105\nM114\n", 1000)
    assert link.take(1000) == b"M105\n"
    assert link.next_line_tick() == 1000 + round(5 * BYTE_TICKS + 0.5)  # 5 more bytes: 0.43 ms
    assert link.take(link.next_line_tick()) == b"M114\n" and link.in_flight == 0


def test_a_later_write_queues_behind_what_is_in_flight():
    link = SerialLink()
    link.send(b"G1 X1\n" + b"x" * 1000 + b"\n", 0)
    link.take(0)
    link.send(b"M105\n", 1)
    assert link.drained_tick(0) == pytest.approx((1001 + 5) * BYTE_TICKS, abs=1)
    assert link.drained_tick(link.in_flight) == 0


def test_m110_then_pipelined_numbered_lines_are_all_accepted():
    """A pipelining host: M110 N0 and 30 numbered lines in one write, no waiting. On a real wire
    M110 has run before N1 has arrived; so here: 31 oks, no line-number error, nothing lost."""
    printer = build_printer()
    printer.take_output()
    burst = "M110 N0\n" + "".join(with_checksum("M105", n) + "\n" for n in range(1, 31))
    start_s = printer.time_s
    printer.receive(burst.encode())
    printer.run_until_idle(10)
    lines = printer.take_output().decode().splitlines()
    assert len(lines) == 31 and all(line.startswith("ok") for line in lines)
    assert printer.reader.last_n == 30
    wire_s = (len(burst) - len("M110 N0\n")) * BYTE_TICKS * TICK_S  # the burst's tail takes its byte times
    assert printer.time_s - start_s == pytest.approx(wire_s, abs=2 * TICK_S)
