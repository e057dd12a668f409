"""The ADC state machine: 10-ISR rounds, 16x oversampling, Marlin's first short reading."""

from hypothesis import given
from hypothesis import strategies as st

from firmware_port.marlin.adc import AdcSequencer
from firmware_port.marlin.constants import TICKS_PER_READING


class RecordingPort:
    """Returns a per-channel value and records when each channel was sampled."""

    def __init__(self, values):
        self.values = values
        self.tick = 0
        self.log = []

    def sample(self, channel):
        self.log.append((self.tick, channel))
        return self.values[channel]


def _run(values, n_ticks):
    port = RecordingPort(values)
    adc = AdcSequencer(len(values), port)
    readings = []
    for tick in range(n_ticks):
        port.tick = tick
        adc.tick()
        if adc.raw_ready:
            readings.append((tick, list(adc.raw)))
            adc.raw_ready = False
    return port.log, readings


@given(st.lists(st.integers(0, 1023), min_size=1, max_size=4))
def test_readings_every_160_ticks_with_16_samples(values):
    log, readings = _run(values, 6 * TICKS_PER_READING)
    ticks = [t for t, _ in readings]
    assert all(b - a == TICKS_PER_READING for a, b in zip(ticks, ticks[1:]))
    first, *rest = readings
    assert first[1] == [15 * v for v in values]  # temp_count starts at 0: 15 samples
    assert all(raw == [16 * v for v in values] for _, raw in rest)


def test_sampling_instants_for_hotend_and_bed():
    log, readings = _run([500, 900], 3 * TICKS_PER_READING)
    assert log[:4] == [(1, 0), (3, 1), (11, 0), (13, 1)]
    assert readings[0][0] == 150  # the 16th StartSampling: tick 15 * 10


def test_unconsumed_readings_are_dropped_like_marlin():
    port = RecordingPort([100])
    adc = AdcSequencer(1, port)
    for _ in range(3 * TICKS_PER_READING):
        adc.tick()
    assert adc.raw == [1500]  # still the first reading: later ones were dropped


class ListPort:
    """Returns pre-drawn samples in order, per channel."""

    def __init__(self, samples):
        self.samples = [list(s) for s in samples]

    def sample(self, channel):
        return self.samples[channel].pop(0)


@given(
    st.integers(0, 9),
    st.integers(0, 15),
    st.booleans(),
    st.integers(0, 400),
    st.randoms(use_true_random=False),
)
def test_skip_equals_tick_by_tick(phase, temp_count, ready, n_ticks, rnd):
    """The fast engine's bulk ADC: same raw values, same ready flag, same counters."""
    samples = [[rnd.randint(0, 1023) for _ in range(n_ticks // 10 + 1)] for _ in range(2)]
    stepped, fast = AdcSequencer(2, ListPort(samples)), AdcSequencer(2, None)
    for adc in (stepped, fast):
        adc.phase, adc.temp_count, adc.raw_ready = phase, temp_count, ready
        adc.acc = [7, 9]
    offsets = fast.sample_offsets(n_ticks)
    for _ in range(n_ticks):
        stepped.tick()
    fast.skip(n_ticks, [samples[ch][: len(offsets[ch])] for ch in range(2)])
    for attr in ("phase", "temp_count", "acc", "raw", "raw_ready"):
        assert getattr(fast, attr) == getattr(stepped, attr), attr


@given(st.integers(0, 9), st.integers(0, 15))
def test_ticks_to_reading_lands_on_the_ready_isr(phase, temp_count):
    adc = AdcSequencer(2, RecordingPort([1, 2]))
    adc.phase, adc.temp_count = phase, temp_count
    n = adc.ticks_to_reading()
    for k in range(1, n + 1):
        adc.tick()
        assert adc.raw_ready == (k == n)
