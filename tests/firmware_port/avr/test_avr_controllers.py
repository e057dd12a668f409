"""The controllers' C on the ATmega328P (simavr) against their Python port, bit for bit.

Property: for any settings in the documented domain and any sequence of readings, targets and
resets, the AVR build and the Python port give the same output and the same state after every
step (the power-up state included). Random readings mostly clamp a controller's output, where a
wrong rounding hides, so the sequences are steered: they start and move around the target, land
where a law switches (the target, +-1 degC, the PID band's +-10 degC, and one step beyond), move slowly (a PID
stays unclamped) with occasional jumps, and ``target()`` pushes hypothesis toward sequences with
more unclamped outputs. A build with one comparison or rounding changed must fail the same
property (``test_a_wrong_build_fails``).
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import Phase, given, settings, target
from hypothesis import strategies as st

from firmware_port.avr.laws import LAWS, OP_RESET, OP_STEP
from firmware_port.avr.runner import LawSim, compare
from firmware_port.fuzzy_pi import N_SETS_MAX, N_SETS_MIN, SEED004_BED, SEED004_HOTEND, FuzzyPiConfig
from firmware_port.fuzzy_pid import LITERAL, READINGS, SEED001_BOARD, FuzzyPidConfig
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX, PidGains
from firmware_port.marlin.pid import BED_GAINS, HOTEND_GAINS
from firmware_port.thermistor import TEMP_ONE

pytestmark = pytest.mark.avr

BAND_Q5 = 10 * TEMP_ONE  # PID_FUNCTIONAL_RANGE
BED_BAND_Q5 = 1 * TEMP_ONE  # BED_LIMIT_SWITCHING: BED_HYSTERESIS - 1
# Errors where a law switches: bang-bang at the target, limit switching at +-1 degC, the PID band.
EDGES_Q5 = tuple(sign * (edge + extra) for edge in (0, BED_BAND_Q5, BAND_Q5) for extra in (0, 1) for sign in (1, -1))
TARGET_MAX_C = 400
TEMP_Q5_MIN, TEMP_Q5_MAX = -(1 << 15), (1 << 15) - 1
MAX_STEPS = 160
# The M303 results of the hardware logs (tools/cli/firmware_report.py PID_CASES) beside Marlin's defaults.
KNOWN_GAINS = (HOTEND_GAINS, BED_GAINS, PidGains(10.45, 1.15, 23.72), PidGains(73.75, 3.09, 439.98))


def gains() -> st.SearchStrategy[PidGains]:
    """Marlin's and measured gains, small gains (outputs rarely clamp), and the whole domain."""
    small = st.builds(PidGains, st.floats(0, 40), st.floats(0, 3), st.floats(0, 300))
    anything = st.builds(PidGains, st.floats(0, KP_MAX), st.floats(0, KI_MAX), st.floats(0, KD_MAX))
    return st.one_of(st.sampled_from(KNOWN_GAINS), small, anything)


def q_multiple(low: int, high: int, frac_bits: int) -> st.SearchStrategy[float]:
    """An exact multiple of 2**-frac_bits whose integer is in low..high."""
    return st.integers(low, high).map(lambda q: q / (1 << frac_bits))


def fuzzy_pi_configs() -> st.SearchStrategy[FuzzyPiConfig]:
    anything = st.builds(
        FuzzyPiConfig,
        err_range_c=q_multiple(1, (1 << 15) - 1, 5),
        derr_range_c=q_multiple(1, (1 << 15) - 1, 5),
        du_range_counts=q_multiple(1, 255 * 16, 4),
        n_sets=st.integers(N_SETS_MIN // 2, N_SETS_MAX // 2).map(lambda k: 2 * k + 1),
        out_max=st.integers(0, 255),
    )
    return st.one_of(st.sampled_from((SEED004_HOTEND, SEED004_BED)), anything)


def fuzzy_pid_settings() -> st.SearchStrategy[tuple[PidGains, FuzzyPidConfig]]:
    anything = st.builds(
        FuzzyPidConfig,
        ke=q_multiple(1, 100 * 4096, 12),
        kec=st.floats(0.001, 100),
        reading=st.sampled_from(READINGS),
        span=q_multiple(0, 16, 4),
    )
    return st.tuples(gains(), st.one_of(st.sampled_from((SEED001_BOARD, FuzzyPidConfig(reading=LITERAL))), anything))


SLOW_MOVES_Q5 = (0, 1, -1, 2, -2, 3, -3)  # the derivative stays small, a PID unclamped
# One byte per step (hypothesis draws the bytes at once, and shrinks them toward 0, a step in place):
SLOW_END = 176  # 0..175: a slow move
MEDIUM_END = 224  # ..223: up to 72 q5 (2.25 degC) either way
EDGE_END = MEDIUM_END + len(EDGES_Q5)  # ..235: onto a switching edge
JUMP_END = 240  # ..239: anywhere, the next two bytes the int16 reading
TARGET_OFF_END = 248  # ..247: target 0 this step; 248..255: a reset before this step


def decode(data: bytes, target_c: int, temp_q5: int) -> list[tuple]:
    """(op, temp_q5, target_c) records from the step bytes, starting from ``temp_q5``."""
    records = []
    i = 0
    while i < len(data):
        code = data[i]
        i += 1
        step_target_c = target_c
        if code < SLOW_END:
            temp_q5 += SLOW_MOVES_Q5[code % len(SLOW_MOVES_Q5)]
        elif code < MEDIUM_END:
            medium = code - SLOW_END
            temp_q5 += ((medium >> 1) + 1) * 3 * (-1 if medium & 1 else 1)
        elif code < EDGE_END:
            temp_q5 = target_c * TEMP_ONE - EDGES_Q5[code - MEDIUM_END]
        elif code < JUMP_END:
            temp_q5 = int.from_bytes(data[i:i + 2].ljust(2, b"\0"), "little", signed=True)
            i += 2
        elif code < TARGET_OFF_END:
            step_target_c = 0
        else:
            records.append((OP_RESET, 0, 0))
        temp_q5 = min(max(temp_q5, TEMP_Q5_MIN), TEMP_Q5_MAX)
        records.append((OP_STEP, temp_q5, step_target_c))
    return records


@st.composite
def readings(draw: st.DrawFn) -> list[tuple]:
    """(op, temp_q5, target_c) records: a walk around a target, steered to where the laws switch."""
    target_c = draw(st.integers(0, TARGET_MAX_C))
    start_q5 = draw(st.one_of(st.sampled_from(EDGES_Q5), st.integers(-2 * BAND_Q5, 2 * BAND_Q5)))
    n_steps = draw(st.integers(1, MAX_STEPS))
    return decode(draw(st.binary(min_size=n_steps, max_size=n_steps)), target_c, target_c * TEMP_ONE + start_q5)


CONTROLLERS = {
    "pid": gains(),
    "pid_in_band": gains(),
    "bangbang_hotend": st.none(),
    "bangbang_bed": st.none(),
    "bangbang_bed_limit": st.none(),
    "fuzzy_pi": fuzzy_pi_configs(),
    "fuzzy_pid": fuzzy_pid_settings(),
}
# One build per law with a single comparison or rounding changed; each must fail the property within
# MUTANT_EXAMPLES generated cases in every profile (the rarest, limit switching, shows in about 1 case in 16).
MUTANT_EXAMPLES = 200
MUTANTS = {
    "pid": ("pid.c", "shr_round_s32(gains->kp_q12 * e_q5, P_SHIFT)", "(gains->kp_q12 * e_q5) >> P_SHIFT"),
    "pid_in_band": ("pid.c", "div_round_s32(d_in_q8 - pid->d_term_q8, D_FILTER_DIVISOR)",
                    "(d_in_q8 - pid->d_term_q8) / D_FILTER_DIVISOR"),
    "bangbang_hotend": ("bangbang.c", "temp_q5 < (int32_t)target_c", "temp_q5 <= (int32_t)target_c"),
    "bangbang_bed": ("bangbang.c", "temp_q5 < target_q5 ?", "temp_q5 <= target_q5 ?"),
    "bangbang_bed_limit": ("bangbang.c", "temp_q5 > target_q5 + BED_BAND_Q5", "temp_q5 >= target_q5 + BED_BAND_Q5"),
    "fuzzy_pi": ("fuzzy_pi.c", "div_round_s32(value_q5 * half, range_q5)", "value_q5 * half / range_q5"),
    "fuzzy_pid": ("fuzzy_pid.c", "div_round_s32(offset, 24)", "offset / 24"),
}


def unclamped(law_sim: LawSim, settings_: object, records: list[tuple]) -> int:
    """How many steps of the port's output are strictly inside its range (not 0, not full scale)."""
    law = law_sim.law
    port = law.port(settings_)
    count = 0
    for record in records:
        if record[0] == OP_STEP:
            out = law.counts(law.step(port, record))
            count += 0 < out < 255
        else:
            port.reset()
    return count


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n.startswith("fuzzy") else n
                                  for n in CONTROLLERS])  # the fuzzy laws take 20k cycles a call
@given(data=st.data())
def test_avr_build_equals_the_port(name, data, differential, law_sims) -> None:
    settings_ = data.draw(CONTROLLERS[name], label="settings")
    records = data.draw(readings(), label="records")
    if name.startswith("pid"):
        target(unclamped(law_sims[name], settings_, records) / len(records), label="unclamped share")
    differential(name, settings_, records)


@pytest.mark.parametrize("name", MUTANTS)
def test_a_wrong_build_fails(name, avr_toolchain) -> None:
    law = LAWS[name]
    mutant = LawSim(law, replace(law.spec, patch=MUTANTS[name]))

    @settings(phases=[Phase.generate], database=None, derandomize=True, max_examples=MUTANT_EXAMPLES)
    @given(settings_=CONTROLLERS[name], records=readings())
    def same(settings_, records) -> None:
        mismatch = compare(mutant, settings_, records)
        assert mismatch is None, str(mismatch)

    with pytest.raises(AssertionError, match=r"avr -?\d+ port -?\d+"):
        same()
    mutant.close()


def test_the_mutants_exist() -> None:
    """Every controller has a mutant, and the list names only controllers."""
    assert set(MUTANTS) == set(CONTROLLERS) <= set(LAWS)
