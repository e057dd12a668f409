"""A user's controller, unknown to the library: an integer PI with back-calculation anti-windup and its
lane law, declared as docs/architecture.md ("A controller's lane law") shows. The law's step is the
controller's own law: ``update`` runs it on the controller itself (its attributes are the records'
fields), the batch compiles it.

    SPACE  (``twin-tune --controller tests.helpers.integer_pi:SPACE``)
"""

from __future__ import annotations

from firmware_port.fixed import clamp, shr_round
from firmware_port.lane_law import LaneLaw, record_dtype, register
from firmware_port.params import Param, ParamSpace

GAIN_BITS = 8  # kp_q8 counts/C, ki_q8 counts/(C reading), kb_q8: Q8
TEMP_BITS = 5  # celsius_q5
U_BITS = GAIN_BITS + TEMP_BITS  # the output and the integral in Q13 counts
U_MAX = 255 << U_BITS
READING_S = 0.16384  # Marlin's control period


def pi_step(p, s, temp_q5, target_c, board):
    """u = kp e + i, saturated to 0..255; i += ki e + kb (saturated - u): the integral unwinds by what
    the output loses to the saturation (back-calculation). ``p`` and ``s`` hold kp_q8, ki_q8, kb_q8 and
    i_q13."""
    if target_c == 0:
        s.i_q13 = 0
        return 0
    e_q5 = (target_c << TEMP_BITS) - temp_q5
    u_q13 = p.kp_q8 * e_q5 + s.i_q13
    v_q13 = clamp(u_q13, 0, U_MAX)
    s.i_q13 = s.i_q13 + p.ki_q8 * e_q5 + shr_round(p.kb_q8 * (v_q13 - u_q13), GAIN_BITS)
    return shr_round(v_q13, U_BITS) if v_q13 < U_MAX else 255


class IntegerPi:
    """The board interface: reset, update(temp_q5, target_c, now_ms) -> 0..255."""

    check_interval_ms = None

    def __init__(self, kp: float, ki: float, kb: float = 1.0):
        self.kp_q8 = round(kp * (1 << GAIN_BITS))
        self.ki_q8 = round(ki * READING_S * (1 << GAIN_BITS))
        self.kb_q8 = round(kb * (1 << GAIN_BITS))
        self.reset()

    def reset(self) -> None:
        self.i_q13 = 0

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        return pi_step(self, self, temp_q5, target_c, None)


INTEGER_PI_LAW = register(LaneLaw("integer_pi", IntegerPi, record_dtype(("kp_q8", "ki_q8", "kb_q8")),
                                  record_dtype(("i_q13",)), pi_step))

SPACE = ParamSpace("integer_pi", (Param("kp", "counts/C", 1.0, 100.0, 20.0),
                                  Param("ki", "counts/(C s)", 0.01, 10.0, 1.0, log=True)), factory=IntegerPi)
