"""Each tuning rule against its formula's worked values or its defining property."""

import math

import numpy as np
import pytest

from firmware_port.marlin.autotune import relay_gains
from tools.ident.fopdt import Fopdt
from tools.tuning.gains import Gains
from tools.tuning.models import model_of
from tools.tuning.rules import (
    RULES,
    amigo,
    cohen_coon,
    klipper,
    marlin_classic,
    simc,
    tune,
    tyreus_luyben,
    ziegler_nichols_step,
    ziegler_nichols_ultimate,
)
from tools.tuning.ultimate import UltimatePoint, ultimate_point
from twin.plants import SPECS

POINT = UltimatePoint(ku=0.05, tu_s=40.0)  # duty per degC, s: a typical hotend's
FOPDT = Fopdt(gain_c=1.0, time_constant_s=10.0, delay_s=2.0)


def duty(gains: Gains) -> tuple[float, float, float]:
    return gains.duty


def test_ziegler_nichols_ultimate_is_0_6_ku_half_and_eighth_period():
    g = ziegler_nichols_ultimate(POINT)
    assert duty(g) == pytest.approx((0.6 * 0.05, 0.6 * 0.05 / 20.0, 0.6 * 0.05 * 5.0))
    assert (g.ti_s, g.td_s) == pytest.approx((20.0, 5.0))


def test_ziegler_nichols_step_in_terms_of_a_and_l():
    # ZN 1942: a = K L / T = 0.2, Kp = 1.2 / a = 6, Ti = 2 L = 4, Td = L / 2 = 1
    g = ziegler_nichols_step(FOPDT)
    assert g.duty[0] == pytest.approx(6.0)
    assert (g.ti_s, g.td_s) == pytest.approx((4.0, 1.0))


def test_tyreus_luyben_is_ku_over_2_2():
    g = tyreus_luyben(POINT)
    assert g.duty[0] == pytest.approx(0.05 / 2.2)
    assert (g.ti_s, g.td_s) == pytest.approx((88.0, 40.0 / 6.3))


def test_cohen_coon_worked_values():
    """K = 1, T = 10, L = 2 (r = 0.2), worked by hand from the Cohen-Coon table:
    Kp = 5 (4/3 + 0.05) = 6.9167, Ti = 2 (32 + 1.2) / (13 + 1.6) = 4.5479, Td = 8 / 11.4 = 0.70175."""
    g = cohen_coon(FOPDT)
    assert g.duty[0] == pytest.approx(6.9167, rel=1e-4)
    assert (g.ti_s, g.td_s) == pytest.approx((4.5479, 0.70175), rel=1e-4)


def test_cohen_coon_tends_to_ziegler_nichols_gain_for_short_dead_time():
    # for L << T, Cohen-Coon's 4/3 T/(K L) is 10/9 of ZN's 1.2 T/(K L), and Ti -> 32/13 L
    short = Fopdt(1.0, 1000.0, 0.01)
    assert cohen_coon(short).kp / ziegler_nichols_step(short).kp == pytest.approx(10 / 9, rel=1e-4)
    assert cohen_coon(short).ti_s == pytest.approx(32 / 13 * 0.01, rel=1e-3)


def test_amigo_matches_the_formula_and_identify_without_loop_delay():
    # Kp = (0.2 + 0.45 * 5) / 1 = 2.45, Ti = 2 (0.8 + 8) / (2 + 1) = 5.8667, Td = 0.5*2*10/(0.6+10) = 0.9434
    g = amigo(FOPDT)
    assert g.duty[0] == pytest.approx(2.45)
    assert (g.ti_s, g.td_s) == pytest.approx((8.8 * 2 / 3, 10 / 10.6))
    assert (g.kp, g.ki, g.kd) == pytest.approx((255 * 2.45, 255 * 2.45 / (8.8 * 2 / 3), 255 * 2.45 * 10 / 10.6))


def test_simc_example_e1_of_skogestad_2003():
    """Skogestad 2003's Example E1 reduces its sixth-order model by the half rule to a FOPDT with
    k = 1, tau1 = 2.5, theta = 1.47; with tau_c = theta, PI: Kc = 2.5 / (2 * 1.47) = 0.85,
    tauI = min(2.5, 8 * 1.47) = 2.5."""
    g = simc(Fopdt(1.0, 2.5, 1.47))
    assert g.duty == pytest.approx((0.8503, 0.8503 / 2.5, 0.0), rel=1e-3)


def test_simc_tau_c_detunes_and_the_integral_time_switches_at_8_theta():
    slow = Fopdt(2.0, 100.0, 5.0)  # tau1 > 8 theta: tauI = 4 (tau_c + theta) = 40
    assert simc(slow).ti_s == pytest.approx(40.0)
    assert simc(slow).duty[0] == pytest.approx(100.0 / (2.0 * 10.0))
    assert simc(slow, tau_c_s=20.0).kp < simc(slow).kp
    assert simc(Fopdt(2.0, 30.0, 5.0)).ti_s == pytest.approx(30.0)  # tau1 < 8 theta: tauI = tau1
    with pytest.raises(ValueError, match="tau_c_s"):
        simc(slow, tau_c_s=-1.0)


def test_marlin_rule_is_the_firmware_relay_arithmetic():
    """Marlin's M303 with d counts and a swing of 2a degC prints Ku = 4 d / (pi a) on 0..255: the
    same gains come from our ultimate point (Ku in duty) through marlin_classic."""
    d, low_c, high_c, period_ms = 80, 205.0, 215.0, 40000
    ku, _, kp, ki, kd = relay_gains(d, low_c, high_c, period_ms, no_overshoot=False)
    g = marlin_classic(UltimatePoint(float(ku) / 255.0, period_ms / 1000))
    # float32 arithmetic in both: equal to float32 resolution
    assert (g.kp, g.ki, g.kd) == pytest.approx((float(kp), float(ki), float(kd)), rel=1e-6)
    assert g.kp == pytest.approx(0.6 * float(ku), rel=1e-6)


def test_klipper_rule_takes_twice_the_textbook_ku():
    g = klipper(POINT)
    assert g.duty[0] == pytest.approx(1.2 * POINT.ku)
    assert (g.ti_s, g.td_s) == pytest.approx((20.0, 5.0))


def test_bad_models_are_one_line_errors():
    with pytest.raises(ValueError, match="positive gain"):
        amigo(Fopdt(1.0, 10.0, 0.0))
    with pytest.raises(ValueError, match="Ku and Tu"):
        tyreus_luyben(UltimatePoint(math.inf, 10.0))
    with pytest.raises(ValueError, match="unknown rule 'nope'; valid: zn_step"):
        tune("nope", model_of(SPECS["seed001_fopdt"]))


@pytest.mark.slow


def test_registry_tunes_every_seed_plant_with_every_rule():
    """Every rule runs on every seed model with a dead time, gives finite non-negative gains, and
    the ultimate-cycle rules see the model's own crossover."""
    for name in ("seed001_fopdt", "seed002_sopdt", "seed003_third"):
        model = model_of(SPECS[name])
        for rule_name, rule in RULES.items():
            assert rule.description and rule.source
            gains = tune(rule_name, model)
            assert np.all(np.isfinite([gains.kp, gains.ki, gains.kd])) and gains.kp > 0, (name, rule_name)
        assert tune("zn_ultimate", model).duty[0] == pytest.approx(0.6 * ultimate_point(model).ku)
