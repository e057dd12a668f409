"""The tuning layer takes any controller: one defined here, unknown to the library, is tuned by
twin-tune's machinery (the public API of tools.tuning.tuner) on the firmware twin."""

import pytest

from tools.tuning.tuner import Param, ParamSpace, preset_problem, tune


class ClampedPi:
    """A PI on the board's 0..255 scale, integral clamped to the output range: nothing the library knows."""

    check_interval_ms = None

    def __init__(self, kp: float, ki: float):
        self.kp, self.ki = kp, ki
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0

    def update(self, temp_q5: int, target_c: int, now_ms: int) -> int:
        error_c = target_c - temp_q5 / 32
        self.integral = min(max(self.integral + self.ki * error_c * 0.16384, 0.0), 255.0)
        return int(min(max(self.kp * error_c + self.integral, 0.0), 255.0))


@pytest.mark.slow
def test_a_controller_defined_in_a_test_is_tuned_through_the_public_api():
    space = ParamSpace("clamped_pi", (Param("kp", "counts/C", 1.0, 100.0, 60.0),
                                      Param("ki", "counts/(C s)", 0.01, 10.0, 5.0, log=True)), factory=ClampedPi)
    result = tune(preset_problem("hotend_cartridge", 210, controller=space), method="de", budget=60, seed=1)
    (defaults,) = result.references
    assert defaults.method == "defaults" and list(defaults.params) == [60.0, 5.0]
    assert result.best.method == "de" and result.beats(defaults)
    assert space.inside(result.best.params).all() and result.best.run.tripped.sum() == 0
