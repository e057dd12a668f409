"""Per-run conditions: what a logged run declares about itself, for a fit or a prediction.

A run of a pulse test carries its own samples and two conditions the samples do not show: the
part fan's speed (a fraction of full; no log here records it, the README of the run says it) and
the state it starts in. A run at the start of a session starts settled (every node of the model
at its first reading); a later run of the same session starts where the previous one left its
nodes: a cartridge and block still hot inside while the sensor cools, which a uniform start at
the first reading does not know. Such a run names the run it follows, and its prediction carries
the model's state through that run and through the gap between them (heater off, the later
run's fan), from the session's first reading on.

    first = Run("fan_200", t_s, temp_c, duty, fan=1.0)
    later = Run("fan_200_2", t2_s, temp2_c, duty2, fan=1.0, follows=first)
    predicted_c = run_response(fit.spec(), fit.model, ambient_c, later)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tools.ident.response import zoh_response
from twin.plants import Plant, Spec


@dataclass(frozen=True, eq=False)
class Run:
    """One logged run: samples at t_s (s), readings temp_c (C), heater duty 0..1 held from each
    sample; the part fan's fraction of full speed; the run it follows in its session, if any."""

    label: str
    t_s: np.ndarray
    temp_c: np.ndarray
    duty: np.ndarray
    fan: float = 0.0
    follows: Run | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.fan <= 1.0:
            raise ValueError(f"{self.label}: fan must be within 0..1 of full speed, not {self.fan!r}")
        if not len(self.t_s) == len(self.temp_c) == len(self.duty) > 0:
            raise ValueError(f"{self.label}: t_s, temp_c and duty must be non-empty and of one length")
        if self.follows is not None and self.follows.t_s[-1] >= self.t_s[0]:
            raise ValueError(f"{self.label}: follows {self.follows.label}, which ends at {self.follows.t_s[-1]:g} s, "
                             f"but starts at {self.t_s[0]:g} s: a session's runs are in time order")

    @property
    def start(self) -> str:
        """'settled' or 'after <label>': the state the run declares it starts in."""
        return "settled" if self.follows is None else f"after {self.follows.label}"

    def session(self) -> list[Run]:
        """The runs of its session up to this one, first first."""
        chain = [self]
        while chain[-1].follows is not None:
            chain.append(chain[-1].follows)
        return chain[::-1]


def run_response(spec: Spec, model: str, ambient_c: float, run: Run) -> np.ndarray:
    """The plant's reading at the run's samples, from the state the run declares: settled at the
    session's first reading, then carried through every earlier run and gap of the session."""
    session = run.session()
    plant = Plant(model, spec, ambient_c, float(session[0].temp_c[0]))
    out = np.empty(0)
    for i, r in enumerate(session):
        plant.set_inputs(r.fan, 0.0, ambient_c)
        if i:  # the gap since the previous run: heater off
            zoh_response(plant, np.array([session[i - 1].t_s[-1], r.t_s[0]]), np.zeros(2))
        out = zoh_response(plant, r.t_s, r.duty)
    return out
