"""What a heat-and-hold objective needs from a run, accumulated reading by reading (no trace kept).

A tuner scores thousands of runs and needs a few numbers from each: when the reading first came
into a band around the target during the heat-up, how far it went beyond the target then, and from
that reading to the end the summed |error| and |duty change|. The batch twins accumulate those per
lane as they run (``BatchTwin(score=ScoreSpec(...), record=False)``), so the memory a lane needs
does not grow with the horizon; tools/tuning/objectives.py turns the totals into its heater
objective's terms, and its tests check them against the same terms computed from a recorded trace.

The rules (those of ``heater_terms``): rows are the readings from ``skip_rows`` on; a row is in the
heat-up while its time is before ``heatup_end_s``; holding starts at the first heat-up row with
|target - reading| <= ``band_c`` (reached), else at the heat-up's last row (not reached); every row
from there on adds its |error| and, after the first, its |duty - previous duty|.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SCORED, HEAT, LAST_HEAT = 1, 2, 4  # ``score_flags`` bits of a reading row: after the skipped rows, in the heat-up, its last


@dataclass(frozen=True)
class ScoreSpec:
    """The run's target and heat-up: what the accumulators compare the readings with."""

    target_c: float
    start_c: float  # the heat-up's start: its sign says which way "beyond the target" is
    heatup_end_s: float
    band_c: float
    skip_rows: int = 0  # readings left out at the start (Marlin's first reading after reset sums 15 samples)

    @property
    def sign(self) -> float:
        return float(np.sign(self.target_c - self.start_c))

    def flags(self, t_s: np.ndarray, next_t_s: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Bits per reading (times t_s, the next reading's times, global row numbers): scored, in the
        heat-up, the heat-up's last."""
        heat = t_s < self.heatup_end_s
        last = heat & (next_t_s >= self.heatup_end_s)
        return np.where(rows >= self.skip_rows, SCORED, 0) | np.where(heat, HEAT, 0) | np.where(last, LAST_HEAT, 0)


@dataclass(frozen=True)
class ScoreTotals:
    """Per lane (N,): the accumulated inputs of the heater objective; ``first_s`` the first scored row's time."""

    first_s: float
    holding_from_s: np.ndarray  # the row where holding started (reach, or the heat-up's last row)
    reached: np.ndarray  # bool: the band was reached during the heat-up
    max_beyond_c: np.ndarray  # largest excursion beyond the target during the heat-up (may be negative)
    abs_error_sum_c: np.ndarray  # summed |target - reading| while holding
    hold_rows: np.ndarray  # readings while holding
    duty_step_sum: np.ndarray  # summed |duty change| (duty 0..1) between consecutive holding readings

    def lanes(self, index) -> ScoreTotals:
        """The totals of some lanes only."""
        return ScoreTotals(self.first_s, *(np.asarray(getattr(self, f))[index] for f in _LANE_FIELDS))

    @staticmethod
    def join(parts: list[ScoreTotals]) -> ScoreTotals:
        """Lanes of several batches on one clock, side by side."""
        return ScoreTotals(parts[0].first_s, *(np.concatenate([getattr(p, f) for p in parts]) for f in _LANE_FIELDS))


_LANE_FIELDS = ("holding_from_s", "reached", "max_beyond_c", "abs_error_sum_c", "hold_rows", "duty_step_sum")
