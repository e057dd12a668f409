"""A controller family's lane law: how a batch of its controllers runs as lanes of the compiled batch.

``twin.BatchTwin`` runs N boards at once, each lane with its own controller; its compiled loop
(twin/batch_kernel.py) holds the board and the plant, and takes the controller's maths from the
family's lane law, declared beside the family's scalar class (as ``PID_LAW`` beside ``PidFixed``):

- ``params`` and ``state``: the per-lane constants and state as numpy record dtypes (named fields;
  ``record_dtype`` makes int64 ones), and how the batch packs them from its
  controllers (``pack``, ``read``) and writes the state back (``write``). By default a field is
  the scalar controller's attribute of the same name;
- ``step(p, s, temp_q5, target_c, board) -> 0..255``: one reading of one lane, ``p`` and ``s``
  that lane's records (read ``p.kp_q12``, write ``s.i_sum_q5 = ...``), ``board`` the ``BoardInputs``
  record (``amount``, ``fan_speed``, ``e_position_steps``) for a law that reads the rest of the
  firmware, as Marlin's MPC does; what ``update`` returns, bit for bit;
- ``tuning`` and ``tuned``: the parameters the heat-up before the first tuned reading does not read,
  and ``tuned(p, s, temp_q5, target_c) -> bool`` saying whether a reading reads them (the batch
  runs such a heat-up once for lanes alike in everything else: its shared prefix).

The step is plain Python, compiled by twin with numba (``nopython`` mode; ``register`` compiles it once
to check it, firmware_port/law_check.py), so it and every function it calls keep to the subset numba
compiles, as SciPy's ``vectorized`` asks a user's function to take arrays:

- integers (int64: ``+ - * // % << >> & | ^``, ``//`` and ``>>`` floor as in Python) and floats
  (float64, or ``np.float32(...)`` for a float32 law), ``abs``, ``min``, ``max``, comparisons,
  ``if``, ``while``, ``for ... in range(...)``, tuples;
- record fields by attribute, module-level constants (frozen in when compiled) and module-level
  plain functions of the same subset (found through the step's globals and compiled with it);
- no Python objects (lists, dicts, classes, strings), no exceptions with formatted messages, no
  ``checked_s32``-style overflow checks: int64 wraps where a scalar class's Python int would not,
  so keep every intermediate within the widths the scalar class declares.

A family registers its law once (``register``, which checks it: a mistake is a ``LawError`` naming the
law, the line and the field); ``law_for`` finds it by the controller's class. A user's controller gets
the compiled batch the same way (tests/helpers/integer_pi.py: an integer PI whose ``update`` runs its
own step); a controller without a law runs one scalar twin per candidate.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from firmware_port.law_check import check_law


# What a law that reads the board (``BoardInputs``) sees at each reading: the heater's soft-PWM amount
# before the update, the part fan (M106, 0..255), the E stepper's position (int32 steps).
BOARD_INPUTS = np.dtype([("amount", np.int64), ("fan_speed", np.int64), ("e_position_steps", np.int64)])


class ScalarLanes:
    """Any controller on N lanes, one instance per lane called in turn: the numpy lanes' way to run a law
    that is not vectorised (the compiled batch runs the family's lane law)."""

    def __init__(self, controllers: Sequence):
        self.controllers = list(controllers)

    def __repr__(self) -> str:
        return f"ScalarLanes({len(self.controllers)} lanes of {type(self.controllers[0]).__name__})"

    def output(self, temp_q5: np.ndarray, target_c: int, active: np.ndarray, now_ms: int) -> np.ndarray:
        """Each active lane's ``update``: 0..255 (0 elsewhere, where its controller is not called)."""
        out = np.zeros(len(self.controllers), np.int64)
        for lane in np.flatnonzero(active):
            out[lane] = self.controllers[lane].update(int(temp_q5[lane]), target_c, now_ms)
        return out


def record_dtype(fields: Sequence[str] | np.dtype) -> np.dtype:
    """A record dtype: the given one, or int64 fields of the given names."""
    return fields if isinstance(fields, np.dtype) else np.dtype([(name, np.int64) for name in fields])


def field_names(dtype: np.dtype) -> tuple[str, ...]:
    """A record dtype's field names."""
    return dtype.names or ()


def attributes(controllers: Sequence[Any], dtype: np.dtype, names: Sequence[str] | None = None) -> np.ndarray:
    """Each controller's attributes named by the dtype's fields (or ``names`` of them: the others 0), as
    (N,) records."""
    out = np.zeros(len(controllers), dtype)
    for name in field_names(dtype) if names is None else names:
        out[name] = [getattr(c, name) for c in controllers]
    return out


def set_attributes(controllers: Sequence[Any], state: np.ndarray, names: Sequence[str] | None = None) -> None:
    """The records' fields (or ``names`` of them) into each controller's attributes of the same names:
    integers as Python ints, floats as numpy floats of the field's width (a float32 law's state stays so)."""
    for lane, c in enumerate(controllers):
        for name in field_names(state.dtype) if names is None else names:
            value = state[name][lane]
            setattr(c, name, value if state.dtype[name].kind == "f" else value.item())


def scalar_lanes(controllers: Sequence[Any], prev_temp_mode: str) -> ScalarLanes:
    """Each lane its own copy of its controller, reset as a ``Twin`` resets it (the numpy lanes run them)."""
    own = [copy.deepcopy(c) for c in controllers]
    for c in own:
        c.reset()
    return ScalarLanes(own)


@dataclass(frozen=True, eq=False)
class LaneLaw:
    """One controller family's law on the batch's lanes (see the module docstring).

    ``lanes(controllers, prev_temp_mode)`` builds what the numpy lanes run (default: one scalar
    copy per lane, ``ScalarLanes``); ``pack``, ``read`` and ``write`` take that object (default:
    attributes of its ``controllers``)."""

    name: str
    controller: type
    params: np.dtype
    state: np.dtype
    step: Callable[..., int]
    tuning: tuple[str, ...] = ()
    tuned: Callable[..., bool] | None = None
    lanes: Callable[[Sequence[Any], str], Any] = scalar_lanes
    pack: Callable[[Any], np.ndarray] | None = None
    read: Callable[[Any], np.ndarray] | None = None
    write: Callable[[Any, np.ndarray], None] | None = None
    reads_board: bool = False  # the step reads ``board`` (the fan and the E stepper: the batch tracks them)
    fits: Callable[[Any], bool] | None = None  # which instances of ``controller`` the law runs (default: all)
    untuned: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        unknown = set(self.tuning) - set(field_names(self.params))
        if unknown:
            raise ValueError(f"lane law {self.name}: tuning names {sorted(unknown)}, not parameters")
        if self.tuning and self.tuned is None:
            raise ValueError(f"lane law {self.name}: tuning parameters need tuned(p, s, temp_q5, target_c)")
        object.__setattr__(self, "untuned", tuple(n for n in field_names(self.params) if n not in self.tuning))

    def pack_params(self, control: Any) -> np.ndarray:
        """The lanes' parameters, (N,) records of ``params``."""
        return self.pack(control) if self.pack else attributes(control.controllers, self.params)

    def read_state(self, control: Any) -> np.ndarray:
        """The lanes' state, (N,) records of ``state``."""
        return self.read(control) if self.read else attributes(control.controllers, self.state)

    def write_state(self, control: Any, state: np.ndarray) -> None:
        """The state the compiled loop left, back into the numpy lanes' controllers."""
        if self.write:
            self.write(control, state)
        else:
            set_attributes(control.controllers, state)

    def __repr__(self) -> str:
        return f"LaneLaw({self.name!r}, controller={self.controller.__name__})"


LAWS: dict[type, LaneLaw] = {}


def register(law: LaneLaw, *, check: bool = True) -> LaneLaw:
    """Make ``law`` the lane law of its controller class (a later registration replaces it), once it is checked
    (firmware_port/law_check.py: compiled once on a tiny input; a mistake is a LawError in one paragraph).
    The library's own laws pass ``check=False``: their tests check them, and checking them at import would
    load numba for every command."""
    if check:
        check_law(law, BOARD_INPUTS)
    LAWS[law.controller] = law
    return law


def law_for(controller: object) -> LaneLaw | None:
    """The lane law registered for the controller's class, if it runs this instance."""
    law = LAWS.get(type(controller))
    return law if law is not None and (law.fits is None or law.fits(controller)) else None
