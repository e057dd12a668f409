"""The batch's shared prefix (``BatchTwin._shared_prefix``): lanes that would run the same periods until
their controllers first read their own tuning run them once. Contract: every lane of a batch reads,
records and scores exactly what the same lane run in a batch of its own (where nothing is shared)
does, bit for bit, floats included (the same kernel runs the same operations); and the prefix is
really shared where lanes agree (a PID heat-up), and not where they differ before their tuning
matters (a prev-temperature mode, a noise stream).
"""

from __future__ import annotations

import numpy as np
import pytest

from firmware_port.fuzzy_pi import SEED004_HOTEND, FuzzyPi
from firmware_port.marlin.bangbang import BangBangHotend
from firmware_port.marlin.pid import PREV_TEMP_EVERY_SAMPLE, PREV_TEMP_IN_BAND, PidFixed, PidGains
from twin import batch as batch_module
from twin.batch import BatchTwin
from twin.plants import ONION_RADIATING_PARAMS, make_plant
from twin.streaming import ScoreSpec

TARGET_C = 210
READING_S = 0.16384


def _run(controllers, preset: str = "hotend_cartridge", events=((0.5, TARGET_C),), duration_s: float = 160.0,
         plant_params: dict | None = None, **options) -> BatchTwin:
    batch = BatchTwin(make_plant(preset, **(plant_params or {})), controllers, kernel="numba",
                      score=ScoreSpec(TARGET_C, 25.0, 100.0, 2.0, 1), threads=1, **options)
    for at_s, target_c in events:
        batch.schedule(at_s, lambda b, c=target_c: b.set_target(c))
    batch.run_until(duration_s)
    return batch


def _lane_options(options: dict, lane: int) -> dict:
    """A lane's own noise and seed out of per-lane batch options."""
    return {k: (v[lane] if isinstance(v, list) else v) for k, v in options.items()}


def _assert_each_lane_runs_as_alone(make, n: int, **kwargs) -> BatchTwin:
    """Every lane of ``make()``'s batch equals its controller in a batch of one, in every record."""
    options = kwargs.pop("options", {})
    batch = _run(make(), **kwargs, **options)
    together = batch.result().hotend
    for lane in range(n):
        alone = _run([make()[lane]], **kwargs, **_lane_options(options, lane))
        assert alone.shared_lane_periods == 0
        single = alone.result().hotend
        for field in ("measured_c", "duty", "block_c", "sensor_c"):
            np.testing.assert_array_equal(getattr(together, field)[:, lane], getattr(single, field)[:, 0], err_msg=field)
        np.testing.assert_array_equal(batch.score_i[lane], alone.score_i[0])
        np.testing.assert_array_equal(batch.score_f[lane], alone.score_f[0])
        assert batch.lanes.trip_code[lane] == alone.lanes.trip_code[0]
    return batch


def _pids(mode: str = PREV_TEMP_EVERY_SAMPLE):
    return [PidFixed(PidGains(22.2, 1.08, 114.0), mode), PidFixed(PidGains(40.0, 3.0, 60.0), mode),
            PidFixed(PidGains(12.0, 0.4, 100.0), mode)]


def test_pid_lanes_share_their_heat_up_and_each_runs_as_alone():
    batch = _assert_each_lane_runs_as_alone(_pids, 3)
    assert batch.shared_lane_periods > 2 * 0.5 * 160.0 / READING_S  # two lanes took over half their periods


def test_a_dead_time_plant_shares_its_ring_of_pulses():
    batch = _assert_each_lane_runs_as_alone(_pids, 3, preset="seed001_fopdt")
    assert batch.shared_lane_periods > 0


@pytest.mark.parametrize("headroom_c", [batch_module.TARGET_HEADROOM_C, -40.0])
def test_a_radiating_plant_shares_its_heat_up(monkeypatch, headroom_c):
    """With tables built up front past the target, and with tables that end below the band (-40 C of
    headroom: bins to 190 C), so that the probe and the shared run stop for a bin, grow the tables
    and go on, as every lane does."""
    monkeypatch.setattr(batch_module, "TARGET_HEADROOM_C", headroom_c)
    batch = _assert_each_lane_runs_as_alone(_pids, 3, plant_params=ONION_RADIATING_PARAMS)
    assert batch.shared_lane_periods > 2 * 0.5 * 160.0 / READING_S


def test_lanes_apart_before_their_tuning_matters_do_not_share():
    """Prev-temperature modes differ outside the band; noise streams differ from the first sample."""
    mixed = lambda: _pids(PREV_TEMP_EVERY_SAMPLE)[:2] + _pids(PREV_TEMP_IN_BAND)[:2]  # noqa: E731
    batch = _assert_each_lane_runs_as_alone(mixed, 4)
    assert 0 < batch.shared_lane_periods < 2 * 160.0 / READING_S  # one lane of each mode takes over
    noisy = _assert_each_lane_runs_as_alone(_pids, 3, options={"noise_lsb": 1.0, "seed": [1, 2, 3]})
    assert noisy.shared_lane_periods == 0
    same_seed = _assert_each_lane_runs_as_alone(_pids, 3, options={"noise_lsb": 1.0, "seed": [4, 4, 4]})
    assert same_seed.shared_lane_periods > 0


def test_a_later_stretch_shares_only_what_is_still_alike():
    """A target change after the lanes diverged: nothing alike is left, so each lane runs on its own."""
    events = ((0.5, TARGET_C), (120.0, 180))
    batch = _assert_each_lane_runs_as_alone(_pids, 3, events=events, duration_s=200.0)
    first_stretch_only = _run(_pids(), events=events[:1], duration_s=120.0).shared_lane_periods
    assert batch.shared_lane_periods == first_stretch_only


def test_controllers_that_read_their_tuning_at_once_share_only_with_twins():
    """Bang-bang has no tuning: its lanes share everything. A fuzzy PI's every constant is read from the
    first reading with a target: only a lane with the very same constants shares, the whole run."""
    bang = _assert_each_lane_runs_as_alone(lambda: [BangBangHotend(), BangBangHotend()], 2, duration_s=60.0)
    assert bang.shared_lane_periods >= 60.0 / READING_S  # the second lane ran none of its own
    twins = lambda: [FuzzyPi(SEED004_HOTEND), FuzzyPi(SEED004_HOTEND.__class__(30.0, 1.0, 16.0)),  # noqa: E731
                     FuzzyPi(SEED004_HOTEND)]
    fuzzy = _assert_each_lane_runs_as_alone(twins, 3, duration_s=60.0)
    assert 60.0 / READING_S <= fuzzy.shared_lane_periods < 2 * 60.0 / READING_S  # the third lane: the first's
