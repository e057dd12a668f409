"""Bounded memory for long serial sessions: the RX ring, the host-side buffer, the plant cache.

tracemalloc measures what Python allocates while the printer takes a flood; the numbers are
bounds on growth, far below the flood's size (a buffer that kept the bytes would grow by all
of them), not timings.
"""

from __future__ import annotations

import os
import tracemalloc

import numpy as np
import pytest
import serial

import protocol  # noqa: F401  registers twin://
from protocol.printer import RX_CAPACITY, WIRE_BUFFER_BYTES
from protocol.build import build_printer
from protocol.server import HOST_BUFFER_BYTES
from twin.linear import MAX_CACHED_MODELS, MAX_CACHED_RUNS

FLOOD_BYTES = 8 * 1024 * 1024
CHUNK = b"M105\n" * 800  # 4000 bytes, a pty read's worth
N_MOVES = int(os.environ.get("N_MOVES", "2000"))
# The host's writes wait for the 115200-baud wire, so the clock runs through the flood (12 virtual
# minutes) and the plant caches its run shapes (bounded: twin/linear.py MAX_CACHED_RUNS maps of
# up to ~45 kB): generous against allocator noise, the flood is still 3 x larger.
GROWTH_BOUND_BYTES = 512 * 1024 + MAX_CACHED_RUNS * 45_000


def busy_printer():
    """A printer in an hour's dwell with its 4-slot queue full: the main loop takes no more lines
    (the flood below is 12 minutes of 115200-baud wire)."""
    printer = build_printer(with_bed=False)
    printer.receive(b"G4 S3600\nM105\nM105\nM105\nM105\n")
    printer.run_for(0.01)  # the four lines arrive behind the first (30 bytes: 2.6 ms of wire)
    printer.take_output()
    assert printer.executing and len(printer.queue) == 4
    return printer


def flood(receive, n_bytes: int) -> int:
    """Feed ``n_bytes`` through ``receive`` in pty-sized chunks; the peak growth in bytes."""
    tracemalloc.start()
    base, _ = tracemalloc.get_traced_memory()
    for _ in range(n_bytes // len(CHUNK)):
        receive(CHUNK)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak - base


@pytest.mark.slow
def test_a_flood_while_busy_fills_the_128_byte_ring_and_the_rest_is_lost():
    printer = busy_printer()
    growth = flood(printer.receive, FLOOD_BYTES)
    assert len(printer._rx) == RX_CAPACITY  # 127 bytes wait, as in MarlinSerial's ring
    sent = FLOOD_BYTES // len(CHUNK) * len(CHUNK)
    # The host's writes waited for the wire (at most WIRE_BUFFER_BYTES ahead of it); what arrived
    # beyond the ring was lost.
    assert printer.link.in_flight <= WIRE_BUFFER_BYTES
    assert printer.rx_dropped == sent - RX_CAPACITY - printer.link.in_flight
    assert growth < GROWTH_BOUND_BYTES
    # The ring is full, so even an M108 would be lost now (as on the board). The dwell ends by
    # itself, the queue and the ring drain, and the printer answers again.
    printer.receive(b"M108\n")
    assert printer.executing
    printer.run_until_idle(4000)
    assert not printer.executing and not printer._rx
    printer.take_output()
    printer.receive(b"\nM105\n")  # the flood's last partial line ends first
    printer.run_until_idle(1)  # the M105 arrives 5 byte times behind
    assert printer.take_output().decode().splitlines()[-1].startswith("ok T:")


@pytest.mark.slow
def test_a_host_that_never_reads_stalls_the_printer_not_the_memory():
    with serial.serial_for_url("twin://?idle_speed=0", timeout=0) as port:
        growth = flood(port.write, FLOOD_BYTES)
        waiting = len(port._received) + len(port.printer._out)
        # The replies to the lines read before the host's buffer filled (one chunk's M105s,
        # 40 bytes each), then Marlin's writes block: flat, whatever the flood's size.
        assert waiting < HOST_BUFFER_BYTES + len(CHUNK) * 10
        assert growth < GROWTH_BOUND_BYTES
        assert port.printer.rx_dropped > FLOOD_BYTES / 2
        port.reset_input_buffer()
        port.write(b"M105\n")
        port.timeout = 60  # a hang guard: the read ends at the mark
        assert port.read_until(b"ok T:").endswith(b"ok T:")  # it serves again once the host reads


@pytest.mark.slow


def test_moves_at_ever_new_feeds_keep_the_model_cache_bounded():
    """Each feed rate is a new filament flow, so a new plant discretisation (about 1 MB); the
    full 20 000-move stream is ``N_MOVES=20000`` (five minutes here), CI runs 2 000."""
    printer = build_printer(with_bed=False)
    plant = printer.twin.plants[0]
    rng = np.random.default_rng(5)
    printer.receive(b"M83\n")
    sizes = []
    for i, feed in enumerate(rng.uniform(60, 1500, N_MOVES)):
        printer.receive(f"G1 E0.05 F{feed:.1f}\n".encode())
        printer.run_until_idle(10)
        printer.take_output()
        if i % 500 == 499:
            sizes.append(len(plant._models))
    assert len(set(sizes)) == 1 and sizes[0] <= MAX_CACHED_MODELS
