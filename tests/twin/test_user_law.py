"""A user's controller declares its lane law and runs on the compiled batch, lane for lane its scalar twin;
one that declares none runs on scalar twins, and the tuning layer says so in one line."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.integer_pi import SPACE, IntegerPi
from tests.twin.test_batch_paths import _assert_lane_is_the_twin, _batch, _scalar
from tools.tuning.evaluate import preset_problem
from twin.batch import BatchTwin
from twin.batch_kernel import KERNELS
from twin.plants import make_plant

DURATION_S = 150.0


def _pis() -> list[IntegerPi]:
    """Gains that saturate through the heat-up (the integral unwinding by back-calculation), one without
    back-calculation (it winds up and overshoots), and a gentle one."""
    return [IntegerPi(20.0, 1.0), IntegerPi(20.0, 1.0, kb=0.0), IntegerPi(5.0, 0.2, kb=0.5)]


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_users_integer_pi_runs_on_the_batch_as_its_scalar_twin(kernel):
    """Its lane law on the batch (compiled, and as scalar copies on the numpy lanes): each lane reads,
    drives and ends with the state of the controller on its own ``Twin``."""
    batch = _batch("hotend_cartridge", _pis(), DURATION_S, kernel=kernel)
    for lane, controller in enumerate(_pis()):
        twin = _scalar("hotend_cartridge", controller, DURATION_S)
        _assert_lane_is_the_twin(batch, lane, twin)
        assert batch.lanes.control.controllers[lane].i_q13 == twin.board.hotend.controller.i_q13
    duty = batch.result().hotend.duty
    assert (duty == 1.0).any() and not np.array_equal(duty[:, 0], duty[:, 1])  # saturated; kb matters


class LawlessPi(IntegerPi):
    """The same controller as a class of its own that declares no lane law."""


def test_a_controller_without_a_lane_law_runs_on_scalar_twins_and_says_so():
    assert BatchTwin.accepts(IntegerPi(20.0, 1.0)) and not BatchTwin.accepts(LawlessPi(20.0, 1.0))
    with pytest.raises(TypeError, match="lane 0: a batch runs controllers with a lane law"):
        BatchTwin(make_plant("hotend"), [LawlessPi(20.0, 1.0)])
    assert preset_problem("hotend_cartridge", 210, controller=SPACE).batched
    lawless = SPACE.__class__(SPACE.name, SPACE.params, factory=LawlessPi)
    with pytest.warns(UserWarning, match=r"^controller LawlessPi declares no lane law \(firmware_port/lane_law.py\): "
                                         r"each candidate runs on a scalar twin of its own"):
        assert not preset_problem("hotend_cartridge", 210, controller=lawless).batched
