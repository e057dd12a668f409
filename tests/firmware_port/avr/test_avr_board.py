"""The board's per-reading and per-ISR C on the ATmega328P (simavr) against the Python port, bit for bit.

The thermistor lookup is checked on every raw value an ADC sum can take (exhaustive) and on
hypothesis-drawn int16 values beyond; the x16 ADC sums and the soft PWM on hypothesis-drawn ISR
sequences long enough to cross readings (160 ISRs) and PWM periods (127 ISRs), with the main loop
taking readings and writing amounts at drawn moments. A build with one comparison or rounding
changed must fail (``test_a_wrong_build_fails``).
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from firmware_port.avr.laws import LAWS, OP_STEP
from firmware_port.avr.runner import LawSim, compare
from firmware_port.marlin.constants import SOFT_PWM_MAX, SOFT_PWM_PERIOD_TICKS, TICKS_PER_READING
from firmware_port.thermistor import ADC_MAX, MAX_RAW_THERMISTOR_VALUE

pytestmark = pytest.mark.avr

RAW_VALUES = [(OP_STEP, raw) for raw in range(MAX_RAW_THERMISTOR_VALUE + 1)]


def test_thermistor_lookup_on_every_raw_value(differential) -> None:
    differential("thermistor", None, RAW_VALUES)


@given(raws=st.lists(st.integers(-(1 << 15), (1 << 15) - 1), min_size=1, max_size=64))
def test_thermistor_lookup_beyond_the_adc(raws, differential) -> None:
    differential("thermistor", None, [(OP_STEP, raw) for raw in raws])


@st.composite
def adc_isrs(draw: st.DrawFn) -> list[tuple]:
    """(op, take, conversion0, conversion1) per ISR: 1..4 readings' worth, the main loop taking
    the readings (clearing raw_ready) at drawn ISRs, or not, so that sums are dropped."""
    n_isrs = draw(st.integers(1, 4 * TICKS_PER_READING))
    takes = draw(st.binary(min_size=n_isrs, max_size=n_isrs))
    conversion = st.one_of(st.sampled_from((0, 1, ADC_MAX - 1, ADC_MAX)), st.integers(0, ADC_MAX))
    pins = draw(st.lists(st.tuples(conversion, conversion), min_size=1, max_size=16))
    return [(OP_STEP, int(takes[i] >= 0xF0), *pins[i % len(pins)]) for i in range(n_isrs)]


@st.composite
def pwm_isrs(draw: st.DrawFn) -> list[tuple]:
    """(op, write, amount0, amount1) per ISR: 1..4 periods, the main loop writing amounts (0..127,
    the ends often) on drawn ISRs."""
    n_isrs = draw(st.integers(1, 4 * SOFT_PWM_PERIOD_TICKS))
    writes = draw(st.binary(min_size=n_isrs, max_size=n_isrs))
    amount = st.one_of(st.sampled_from((0, 1, SOFT_PWM_MAX - 1, SOFT_PWM_MAX)), st.integers(0, SOFT_PWM_MAX))
    amounts = draw(st.lists(st.tuples(amount, amount), min_size=1, max_size=16))
    return [(OP_STEP, writes[i] & 3 if writes[i] >= 0xC0 else 0, *amounts[i % len(amounts)]) for i in range(n_isrs)]


@given(records=adc_isrs())
def test_adc_sums(records, differential) -> None:
    differential("adc", None, records)


@given(records=pwm_isrs())
def test_soft_pwm(records, differential) -> None:
    differential("softpwm", None, records)


MUTANT_EXAMPLES = 200  # generated cases a wrong build must fail within, in every profile
CASES = {"thermistor": st.just(RAW_VALUES), "adc": adc_isrs(), "softpwm": pwm_isrs()}
MUTANTS = {
    "thermistor": ("thermistor.c", "div_round_s32(((int32_t)raw - v0) * span_q5, (int32_t)v1 - v0)",
                   "((int32_t)raw - v0) * span_q5 / ((int32_t)v1 - v0)"),
    "adc": ("adc.c", "if (!adc->raw_ready)", "if (1)"),
    "softpwm": ("softpwm.c", "if (pwm->count[ch] <= tmp)", "if (pwm->count[ch] < tmp)"),
}


@pytest.mark.parametrize("name", MUTANTS)
def test_a_wrong_build_fails(name, avr_toolchain) -> None:
    law = LAWS[name]
    mutant = LawSim(law, replace(law.spec, patch=MUTANTS[name]))

    @settings(phases=[Phase.generate], database=None, derandomize=True, max_examples=MUTANT_EXAMPLES)
    @given(records=CASES[name])
    def same(records) -> None:
        mismatch = compare(mutant, None, records)
        assert mismatch is None, str(mismatch)

    with pytest.raises(AssertionError, match=r"avr -?\d+ port -?\d+"):
        same()
    mutant.close()
