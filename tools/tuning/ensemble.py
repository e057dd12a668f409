"""Plant ensembles for robust tuning: the plants a source allows, with the sensor noise a printer has.

A candidate is scored on every member of its problem's ensemble, and the costs are reduced to one
robust statistic (``STATISTICS``; default ``mean_std``, the mean plus one standard deviation over
the members: every member's chatter and hold error count, and a trip in any member (10,000 s of
cost) outweighs everything else. ``worst`` would let the hardest corner alone decide and leave the
nominal plant's behaviour unscored). A member is the nominal plant with some parameters changed, a noise level
in ADC LSB and a noise seed.

Where the parameters may lie (``Uncertain``: a range and its source) comes from the plant's source: a
fit's standard errors and the plausible ranges of what the data could not identify
(tools/ident), or, for a preset that states none, ``DEFAULT_SPREAD`` (+-20 %) on its lag and on its
loss. 20 % is a stated default, not a measurement: about the difference a silicone sock, a
re-seated thermistor or another cartridge of the same rating makes, and wider than the standard
errors of the fits to the hotend captures, so that the nominal fit is not the only plant a tune
has seen. A group's k terms share it as +-20 %/sqrt(k) each: they err independently, and a corner
moves them all at once, so +-20 % on each (a cartridge hotend's three lag terms stacked) would be a
lag change of about +-35 %, an ensemble no gains hold without duty chatter (docs/tuning.md).

The parameters fall in groups by what they do to the loop (``GROUPS``): ``lag`` (heater to
sensor: less sensor responsiveness or cartridge conductance, more cartridge capacity, longer
transfer-function lags and dead time), ``loss`` (more ambient, fan and radiative transfer; less
transfer-function gain) and ``capacity`` (the block's heat capacity). The members are the nominal
plant and every corner of the groups' box: each group at its "more" or its "less" end (four
corners for a preset's lag and loss). Each member gets its own noise seed at ``noise_lsb``
(default 1 LSB: the M303 captures' readings scatter by 1.0 and 2.9 LSB, docs/validation.md).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields

import numpy as np

from twin.plants import Spec, respec

DEFAULT_SPREAD = 0.2  # +-20 % on the lag and loss terms where the source states no spread (see above)
DEFAULT_NOISE_LSB = 1.0
STATISTICS = ("worst", "mean", "mean_std")  # max over members; mean; mean + one standard deviation
DEFAULT_STATISTIC = "mean_std"
# A search runs every candidate on at least this many noisy runs, spread over the members (a member's
# seeds: ceil(SEARCH_RUNS / members)): a trip that a marginal candidate shows on one draw in three is seen
# in the search, where one draw per member of hotend_cartridge's five let the proof's ten find it (4 of 10
# on a corner). More members need fewer seeds each: the draws differ from member to member as well.
SEARCH_RUNS = 15
SEED_STRIDE = 1000  # a member's further seeds: its own plus multiples of this (members' seeds are 1, 2, ...)

# field -> (group, +1 if a larger value means "more" of the group, else -1)
GROUPS: dict[str, tuple[str, int]] = {
    "sensor_responsiveness_per_s": ("lag", -1),
    "cartridge_xfer_w_k": ("lag", -1),
    "cartridge_heat_capacity_j_k": ("lag", +1),
    "lag1_s": ("lag", +1),
    "lag2_s": ("lag", +1),
    "lag3_s": ("lag", +1),
    "time_constant_s": ("lag", +1),
    "delay_s": ("lag", +1),
    "ambient_xfer_w_k": ("loss", +1),
    "fan_ambient_xfer_w_k": ("loss", +1),
    "radiating_area_m2": ("loss", +1),
    "gain": ("loss", -1),
    "power_w": ("loss", -1),  # less power: the same losses weigh more (a fit holds P/C and P/A)
    "ambient_c": ("loss", -1),  # a relay fit's loss is anchored to its ambient: a colder room loses more
    "block_heat_capacity_j_k": ("capacity", +1),
}
DEFAULT_SPREAD_GROUPS = ("lag", "loss")
PRESET_STATED = ("power_w", "ambient_c")  # a preset states its heater's rating and its room: a fit's source spreads them


@dataclass(frozen=True)
class Uncertain:
    """A parameter of the plant spec that may lie anywhere in [low, high], and why."""

    name: str
    low: float
    high: float
    source: str

    def __post_init__(self) -> None:
        if self.name not in GROUPS:
            raise ValueError(f"{self.name!r} is not a plant parameter the ensemble spreads ({', '.join(GROUPS)})")
        if not self.low <= self.high:
            raise ValueError(f"{self.name}: low {self.low!r} above high {self.high!r}")


@dataclass(frozen=True)
class Member:
    """One plant of the ensemble: parameter changes from the nominal spec (and the spec they make, where
    the source builds it: a fit rescales what its data anchor), ADC noise and its seed."""

    label: str
    changes: tuple[tuple[str, float], ...]
    noise_lsb: float
    seed: int
    built: Spec | None = None
    ambient_c: float | None = None  # the room this plant was fitted in (None: the problem's)

    def spec(self, nominal: Spec) -> Spec:
        if self.built is not None:
            return self.built
        return respec(nominal, dict(self.changes)) if self.changes else nominal


@dataclass(frozen=True)
class Ensemble:
    """The members a candidate is scored on and the statistic that reduces their costs."""

    members: tuple[Member, ...]
    statistic: str = DEFAULT_STATISTIC
    spread: tuple[Uncertain, ...] = ()
    seeds: int = 1  # noise seeds each member runs on in a search (the member's seed and on)
    kind: str = "plants of the ensemble"  # what the members are, for a verdict's line

    def __post_init__(self) -> None:
        if not self.members:
            raise ValueError("an ensemble needs at least one member")
        if self.statistic not in STATISTICS:
            raise ValueError(f"unknown statistic {self.statistic!r}; choose one of: {', '.join(STATISTICS)}")
        if self.seeds < 1:
            raise ValueError(f"seeds={self.seeds!r}: at least one noise seed per member")

    @property
    def size(self) -> int:
        return len(self.members)

    @property
    def lanes(self) -> int:
        """Runs per candidate in a search: every member on each of its seeds."""
        return self.size * self.seeds

    def runs(self) -> list[tuple[Member, int]]:
        """(member, seed) of each run of a search, member-major."""
        return [(m, m.seed + SEED_STRIDE * k) for m in self.members for k in range(self.seeds)]

    def reduce(self, costs: np.ndarray) -> np.ndarray:
        """Costs (runs, N) of a search, member-major -> the robust statistic (N,)."""
        return self.statistic_of(np.asarray(costs, float).reshape(self.lanes, -1))

    def statistic_of(self, costs: np.ndarray) -> np.ndarray:
        """The statistic over axis 0 of costs (rows, N)."""
        if self.statistic == "worst":
            return costs.max(axis=0)
        if self.statistic == "mean":
            return costs.mean(axis=0)
        return costs.mean(axis=0) + costs.std(axis=0)

    @property
    def corners(self) -> tuple[Member, ...]:
        """The members at the box's corners (every member but the nominal one, when spread)."""
        return self.members[1:]

    def describe(self) -> str:
        noise = sorted({m.noise_lsb for m in self.members})
        spread = "; ".join(f"{u.name} {u.low:.4g}..{u.high:.4g} ({u.source})" for u in self.spread) or "none"
        return (f"{self.size} members ({len(self.corners)} corner plants), ADC noise {', '.join(f'{n:g}' for n in noise)}"
                f" LSB on {self.seeds} seeds each, statistic {self.statistic}; spread: {spread}")


NOMINAL = Ensemble((Member("nominal", (), 0.0, 0),), "mean")


def preset_spread(spec: Spec, fraction: float = DEFAULT_SPREAD,
                  groups: Sequence[str] = DEFAULT_SPREAD_GROUPS) -> tuple[Uncertain, ...]:
    """+-fraction on each of the given groups (``DEFAULT_SPREAD_GROUPS``: lag and loss), shared by its k
    non-zero parameters as +-fraction/sqrt(k) each (the ratings a preset states, ``PRESET_STATED``, stay)."""
    names = [f.name for f in fields(spec) if f.name in GROUPS and f.name not in PRESET_STATED
             and GROUPS[f.name][0] in groups and getattr(spec, f.name)
             and not (f.name == "radiating_area_m2" and not getattr(spec, "emissivity", 0.0))]  # no emissivity: inert
    per_group = {g: sum(GROUPS[n][0] == g for n in names) for g in groups}
    out = []
    for name in names:
        value, count = getattr(spec, name), per_group[GROUPS[name][0]]
        term = fraction / math.sqrt(count)  # the group's terms err independently: root-sum-square to fraction
        low, high = sorted((value * (1 - term), value * (1 + term)))
        out.append(Uncertain(name, low, high, f"preset, default +-{fraction:.0%} per group: +-{term:.1%} on each of {count}"))
    return tuple(out)


def search_seeds(members: int) -> int:
    """Noise seeds per member in a search: SEARCH_RUNS runs per candidate at least (see above)."""
    return max(1, math.ceil(SEARCH_RUNS / members))


def plant_ensemble(plants: Sequence[tuple[str, Spec, float]], noise_lsb: float = DEFAULT_NOISE_LSB,
                   statistic: str = DEFAULT_STATISTIC, first_seed: int = 1, seeds: int | None = None) -> Ensemble:
    """An ensemble of given plants: (label, spec, ambient_c) each, the first the nominal one, each with its
    own noise seeds (``search_seeds`` unless given; tools/tuning/allowed.py gives a log's plants)."""
    return Ensemble(tuple(Member(label, (), noise_lsb, first_seed + k, spec, ambient_c)
                          for k, (label, spec, ambient_c) in enumerate(plants)), statistic,
                    seeds=seeds or search_seeds(len(plants)), kind="plants the log allows")


def corner_ensemble(spread: Sequence[Uncertain], noise_lsb: float = DEFAULT_NOISE_LSB,
                    statistic: str = DEFAULT_STATISTIC, first_seed: int = 1,
                    build: Callable[..., Spec] | None = None, seeds: int | None = None) -> Ensemble:
    """The nominal plant and every corner of the spread's groups, each with its own noise seeds
    (``search_seeds`` unless given); ``build(**changes)`` makes a corner's spec where the source does (a
    fit's ``spec_with``)."""
    groups = sorted({GROUPS[u.name][0] for u in spread})
    members = [Member("nominal", (), noise_lsb, first_seed)]
    for k, ends in enumerate(itertools.product((+1, -1), repeat=len(groups)) if groups else (), start=1):
        end_of = dict(zip(groups, ends))
        changes = tuple((u.name, u.high if GROUPS[u.name][1] * end_of[GROUPS[u.name][0]] > 0 else u.low)
                        for u in spread)
        label = " ".join(f"{g}{'+' if e > 0 else '-'}" for g, e in end_of.items())
        members.append(Member(label, changes, noise_lsb, first_seed + k, None if build is None else build(**dict(changes))))
    return Ensemble(tuple(members), statistic, tuple(spread), seeds or search_seeds(len(members)),
                    "plants of the spread")
