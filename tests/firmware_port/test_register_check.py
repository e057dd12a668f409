"""``register`` checks a lane law where it is registered: compiled once on a tiny input where numba compiles,
run once as plain Python where it does not (NUMBA_DISABLE_JIT, as the numpy fallback runs), a mistake is a
LawError in one paragraph naming the law, the line of the user's code and the field or name, with the full
message in its details. The laws below are a user's, each broken in one way, and one that is fine."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from firmware_port import lane_law
from firmware_port.fixed import clamp
from firmware_port.lane_law import BOARD_INPUTS, LAWS, LaneLaw, record_dtype, register
from firmware_port.law_check import LawError, check_law
from twin.limits import UserError

try:
    import numba
except ImportError:  # a platform without numba's wheels: only the plain-Python check runs
    numba = None

ROOT = Path(__file__).resolve().parents[2]
GAINS_Q8 = [20, 1]  # a list: numba cannot freeze it into compiled code
PARAMS = record_dtype(("kp_q8",))
STATE = record_dtype(("i_q13",))
COMPILED, PYTHON = "compiled", "python"


class UserPi:
    """A user's integer PI: kp_q8 counts/C (Q8), the integral i_q13 in Q13 counts."""

    check_interval_ms = None

    def __init__(self, kp: float = 20.0):
        self.kp_q8 = round(kp * 256)
        self.reset()

    def reset(self) -> None:
        self.i_q13 = 0

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        return good_step(self, self, temp_q5, target_c, None)


def good_step(p, s, temp_q5, target_c, board):
    e_q5 = (target_c << 5) - temp_q5
    s.i_q13 = s.i_q13 + e_q5
    return clamp((p.kp_q8 * e_q5 + s.i_q13) >> 13, 0, 255)


def field_step(p, s, temp_q5, target_c, board):
    e_q5 = (target_c << 5) - temp_q5
    return clamp((p.kp_q8 * e_q5 + p.kd_q8 * e_q5) >> 13, 0, 255)


def global_step(p, s, temp_q5, target_c, board):
    e_q5 = (target_c << 5) - temp_q5
    return clamp((GAINS_Q8[0] * e_q5) >> 13, 0, 255)


def object_step(p, s, temp_q5, target_c, board):
    helper = UserPi(20.0)
    return clamp(helper.kp_q8, 0, 255)


def arity_step(p, s, temp_q5, target_c, board):
    e_q5 = (target_c << 5) - temp_q5
    s.i_q13 = s.i_q13 + e_q5
    return clamp(e_q5, 0, 255), s.i_q13


def undefined_step(p, s, temp_q5, target_c, board):
    return clamp(temp_q5 * kp_gain_q8, 0, 255)  # noqa: F821 (the mistake under test)


def float_step(p, s, temp_q5, target_c, board):
    return ((target_c << 5) - temp_q5) * 0.5


def short_step(p, s, temp_q5, target_c):
    return 0


def field_tuned(p, s, temp_q5, target_c):
    return temp_q5 > p.band_q5


class KwargPi(UserPi):
    """Its gain set by name, as some users' classes do: the check cannot tell its attributes, so trusts it."""

    def __init__(self, **gains_q8: int):
        for name, value in gains_q8.items():
            setattr(self, name, value)
        self.reset()


def _line(fn, text: str) -> int:
    """The line of this file, inside ``fn``, that holds ``text``."""
    lines, first = inspect.getsourcelines(fn)
    return first + next(i for i, line in enumerate(lines) if text in line)


@pytest.fixture(params=[COMPILED, PYTHON])
def mode(request, monkeypatch):
    """Each check where numba compiles, and where it does not (the step runs once as plain Python)."""
    monkeypatch.setattr(lane_law, "LAWS", dict(LAWS))  # a test's registrations end with it
    if request.param == COMPILED and numba is None:
        pytest.skip("numba is not installed here")
    if request.param == PYTHON and numba is not None:
        monkeypatch.setattr(numba.config, "DISABLE_JIT", True)
    return request.param


def _refused(name: str, step, params=PARAMS, details: bool = True) -> LawError:
    with pytest.raises(LawError) as info:
        register(LaneLaw(name, UserPi, params, STATE, step))
    assert UserPi not in lane_law.LAWS  # a refused law is not registered
    error = info.value
    assert isinstance(error, UserError) and "\n" not in str(error), str(error)
    assert str(error).startswith(f"lane law {name!r} (UserPi): ")
    if details:  # numba's (or Python's) full message, kept out of the one paragraph
        assert error.details and error.__cause__ is not None and "full message is the LawError's details" in str(error)
    return error


def _at(fn, text: str) -> str:
    return f"test_register_check.py line {_line(fn, text)}: {text}"


def test_a_law_that_is_fine_registers(mode):
    law = register(LaneLaw("fine", UserPi, PARAMS, STATE, good_step))
    assert lane_law.law_for(UserPi()) is law


def test_a_record_field_the_class_lacks_names_the_field_and_the_class(mode):
    message = str(_refused("lacks", good_step, record_dtype(("kp_q8", "kd_q8")), details=False))
    assert "'kd_q8' is no attribute of UserPi" in message
    assert f"test_register_check.py line {_line(UserPi, 'class UserPi')}: class UserPi:" in message


def test_a_field_the_records_lack_names_the_field_and_its_line(mode):
    message = str(_refused("no_field", field_step))
    assert "record field 'kd_q8', which its records lack (params: kp_q8; state: i_q13;" in message
    assert _at(field_step, "return clamp((p.kp_q8 * e_q5 + p.kd_q8 * e_q5) >> 13, 0, 255)") in message


def test_a_name_defined_nowhere_names_it_and_its_line(mode):
    message = str(_refused("undefined", undefined_step))
    assert "reads the name 'kp_gain_q8', defined nowhere" in message
    assert f"test_register_check.py line {_line(undefined_step, 'kp_gain_q8')}: " in message


def test_a_wrong_return_arity_names_the_step_and_its_return(mode):
    message = str(_refused("two_values", arity_step, details=False))
    assert "its step arity_step returns 2 values, not one integer 0..255" in message
    assert _at(arity_step, "return clamp(e_q5, 0, 255), s.i_q13") in message


def test_a_float_return_names_the_step_and_its_return(mode):
    message = str(_refused("a_float", float_step, details=False))
    assert "its step float_step returns a float64, not one integer 0..255" in message
    assert _at(float_step, "return ((target_c << 5) - temp_q5) * 0.5") in message


def test_a_step_that_cannot_take_the_batchs_arguments_names_them(mode):
    message = str(_refused("short", short_step, details=False))
    assert "its step short_step cannot take the batch's arguments (p, s, temp_q5, target_c, board)" in message
    assert _at(short_step, "def short_step(p, s, temp_q5, target_c):") in message


def test_tuned_is_checked_as_the_step_is(mode):
    with pytest.raises(LawError) as info:
        register(LaneLaw("tuned_field", UserPi, PARAMS, STATE, good_step, tuning=("kp_q8",), tuned=field_tuned))
    message = str(info.value)
    assert "record field 'band_q5', which its records lack" in message
    assert _at(field_tuned, "return temp_q5 > p.band_q5") in message


def test_a_class_whose_attributes_the_check_cannot_tell_is_trusted(mode):
    law = register(LaneLaw("by_name", KwargPi, PARAMS, STATE, good_step))
    assert lane_law.law_for(KwargPi(kp_q8=5120)) is law


def test_an_untyped_global_names_it_and_its_line(mode):
    if mode == PYTHON:  # plain Python reads a list: only numba refuses it, at register time where it compiles
        register(LaneLaw("list_global", UserPi, PARAMS, STATE, global_step))
        return
    message = str(_refused("list_global", global_step))
    assert "reads the global 'GAINS_Q8', a reflected list(int64)" in message
    assert _at(global_step, "return clamp((GAINS_Q8[0] * e_q5) >> 13, 0, 255)") in message


def test_a_python_object_numba_cannot_type_names_it_and_its_line(mode):
    if mode == PYTHON:
        register(LaneLaw("an_object", UserPi, PARAMS, STATE, object_step))
        return
    message = str(_refused("an_object", object_step))
    assert "reads the global 'UserPi', which numba cannot type (Cannot determine Numba type of <class 'type'>)" \
        in message
    assert _at(object_step, "helper = UserPi(20.0)") in message


@pytest.mark.parametrize("law", sorted(LAWS.values(), key=lambda law: law.name), ids=lambda law: law.name)
def test_every_built_in_law_passes_the_check(law, mode):
    """The library registers its own laws unchecked (at import, numba would load for every command): here they are."""
    check_law(law, BOARD_INPUTS)


# twin-tune --controller my_law:SPACE, the user's module in the current directory.
USER_MODULE = '''
from firmware_port.fixed import clamp
from firmware_port.lane_law import LaneLaw, record_dtype, register
from firmware_port.params import Param, ParamSpace


class Pi:
    check_interval_ms = None

    def __init__(self, kp):
        self.kp_q8 = round(kp * 256)

    def reset(self):
        pass

    def update(self, temp_q5, target_c, now_ms):
        return p_step(self, self, temp_q5, target_c, None)


def p_step(p, s, temp_q5, target_c, board):
    return clamp((p.kp_q8 * ((target_c << 5) - temp_q5) + p.offset_q8) >> 13, 0, 255)


register(LaneLaw("my_p", Pi, record_dtype(("kp_q8",)), record_dtype(()), p_step))
SPACE = ParamSpace("my_p", (Param("kp", "counts/C", 1.0, 100.0, 20.0),), factory=Pi)
'''


@pytest.mark.parametrize("disable_jit", ["0", "1"])
def test_twin_tune_says_a_broken_law_in_one_line_and_exits_2(tmp_path, disable_jit):
    (tmp_path / "my_law.py").write_text(textwrap.dedent(USER_MODULE))
    tune = Path(sys.executable).with_name("twin-tune")
    env = {**os.environ, "NUMBA_DISABLE_JIT": disable_jit, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([str(tune), "--plant", "hotend_cartridge", "--controller", "my_law:SPACE"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=600)
    line = USER_MODULE.splitlines().index("    return clamp((p.kp_q8 * ((target_c << 5) - temp_q5) + p.offset_q8) "
                                          ">> 13, 0, 255)") + 1
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.startswith("twin-tune: error: --controller my_law:SPACE: lane law 'my_p' (Pi): ")
    assert "record field 'offset_q8', which its records lack" in done.stderr
    assert f"my_law.py line {line}: return clamp(" in done.stderr
