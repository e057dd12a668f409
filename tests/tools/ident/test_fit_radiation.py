"""The radiation-like loss in the lumped fits: a synthetic radiating plant's area recovered within
its standard errors and kept by AIC, a linear plant's data keeping the linear loss, the power-free
numbers of a radiating fit against a simulation, twin-fit --loss end to end on the onionheater
no-fan pulse (the hardware_logs fixture: skipped locally and failed in CI without the logs), and the bad
combinations of options."""

import re

import numpy as np
import pytest

from tools.cli.fit import main
from tools.ident.fit import RADIATING_BOUNDS_M2, fit_losses, fit_model
from tools.ident.fopdt import fopdt_equivalent
from tools.ident.response import radiating_response, zoh_response
from tools.ident.result import aic
from tools.validation.plant_check import onion_fit_options
from twin.plants import ONION_RADIATING_PARAMS, Lumped, Plant

AMBIENT_C = 22.0
NOISE_C = 0.3
SIGMAS = 3.0  # the residuals are the seeded Gaussian noise here: Jacobian standard errors hold
AREA_M2 = 0.004  # about the onionheater's fitted effective area (docs/plants.md)
RADIATING = Lumped(40.0, 13.0, 0.1, 0.04, 0.04, emissivity=1.0, radiating_area_m2=AREA_M2)
LINEAR = Lumped(40.0, 13.0, 0.1, 0.086, 0.086)  # the loss a linear fit gives the onionheater pulse
ONION = "klipper_heattest_onionheater_heattest_200.csv"


def _noisy(spec: Lumped, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """1 s samples of an open-loop run from ambient: full power (to about 250 C), off, half, a fifth."""
    t_s = np.arange(0.0, 600.0, 1.0)
    duty = np.select([t_s < 150, t_s < 300, t_s < 450], [1.0, 0.0, 0.5], 0.2)
    clean_c = zoh_response(Plant("truth", spec, AMBIENT_C, AMBIENT_C), t_s, duty)
    return t_s, clean_c + np.random.default_rng(seed).normal(0.0, NOISE_C, len(t_s)), duty


@pytest.fixture(scope="module")
def radiating_choice():
    return fit_losses("two_node", *_noisy(RADIATING, seed=4), ambient_c=AMBIENT_C)


@pytest.mark.slow


def test_radiating_plant_is_recovered_and_kept_by_aic(radiating_choice):
    fits, kept = radiating_choice
    assert kept == "radiating" and aic(fits["radiating"]) < aic(fits["linear"])
    fit = fits["radiating"]
    assert fit.loss == "radiating" and fit.fixed["emissivity"] == 1.0
    truth = {"radiating_area_m2": AREA_M2, "block_heat_capacity_j_k": 13.0, "sensor_responsiveness_per_s": 0.1,
             "ambient_xfer_w_k": 0.04}
    for name, value in truth.items():
        error = fit.std_errors[name]
        assert 0 < error < 0.05 * value, (name, error)  # determined: within 5 % at this noise
        assert abs(fit.params[name] - value) < SIGMAS * error, (name, fit.params[name], error)
    assert fit.rmse_c == pytest.approx(NOISE_C, rel=0.1)  # down to the noise
    assert fits["linear"].rmse_c > 2 * NOISE_C  # a constant loss cannot follow it


@pytest.mark.slow  # shares radiating_choice (about 40 s) with the two above and below
def test_radiating_fit_power_free_numbers_match_a_simulation(radiating_choice):
    """The rise at full power solves P = (A + h(T)) (T - Ta): the fitted plant held at full power for
    40 of its near-ambient loss time constants settles there (e^-40: nothing left), and the FOPDT
    equivalent's gain is that rise."""
    fit = radiating_choice.fits["radiating"]
    derived = fit.derived()
    t_s = np.arange(0.0, 40 * derived["loss_time_constant_s"], 1.0)
    settled_c = radiating_response(Plant("fit", fit.spec(), AMBIENT_C, AMBIENT_C), t_s, np.ones(len(t_s)))[-1]
    assert derived["rise_at_full_power_c"] == pytest.approx(settled_c - AMBIENT_C, abs=0.01)
    # below the linear part's own rise P / A: radiation only adds loss
    assert derived["rise_at_full_power_c"] < fit.values["power_w"] / fit.values["ambient_xfer_w_k"]
    assert fopdt_equivalent(fit).gain_c == pytest.approx(derived["rise_at_full_power_c"], rel=1e-9)


@pytest.mark.slow


def test_fit_model_auto_and_radiating_return_fit_losses_fits(radiating_choice):
    """fit_model's loss="auto" is fit_losses's kept fit, loss="radiating" its radiating one (the same
    computation: equal to the last digits)."""
    t_s, temp_c, duty = _noisy(RADIATING, seed=4)
    for loss in ("auto", "radiating"):
        result = fit_model("two_node", t_s, temp_c, duty, AMBIENT_C, loss=loss)
        assert result.loss == "radiating"
        assert result.params == pytest.approx(radiating_choice.fits["radiating"].params, rel=1e-9)


@pytest.mark.slow


def test_linear_plant_keeps_the_linear_loss():
    """On a plant without the term the extra parameter buys nothing worth its AIC charge. (Nested at
    a bound, AIC would keep it for about one noise draw in twelve: P(chi2_1 > 2) / 2; this seeded
    draw is one of the others, and the area it wants is negligible either way.)"""
    t_s, temp_c, duty = _noisy(LINEAR, seed=5)
    fits, kept = fit_losses("two_node", t_s, temp_c, duty, AMBIENT_C)
    assert kept == "linear" and aic(fits["linear"]) < aic(fits["radiating"])
    linear = fits["linear"]
    assert linear.loss == "linear" and "radiating_area_m2" not in linear.params and "emissivity" not in linear.fixed
    assert abs(linear.params["ambient_xfer_w_k"] - LINEAR.ambient_xfer_w_k) < SIGMAS * linear.std_errors[
        "ambient_xfer_w_k"]
    radiating = fits["radiating"]
    radiation_w_k = radiating.spec().radiation_w_k(float(temp_c.max()), AMBIENT_C)
    assert radiation_w_k < 0.01 * LINEAR.ambient_xfer_w_k  # under 1 % of the loss even at the hottest reading
    assert RADIATING_BOUNDS_M2[0] <= radiating.params["radiating_area_m2"]


@pytest.mark.parametrize("model", ["fopdt", "sopdt"])
@pytest.mark.parametrize("loss", ["radiating", "auto"])
def test_nonlinear_loss_needs_a_lumped_model(model, loss):
    t_s, temp_c, duty = _noisy(LINEAR, seed=6)
    with pytest.raises(ValueError, match=f"loss '{loss}' needs a lumped model .*{model} has no heat-loss term"):
        fit_model(model, t_s, temp_c, duty, loss=loss)
    with pytest.raises(ValueError, match="unknown loss 'cubic'; valid: linear, radiating, auto"):
        fit_model("two_node", t_s, temp_c, duty, loss="cubic")


@pytest.mark.usefixtures("hardware_logs")
def test_onionheater_pulse_refit_is_the_stored_radiating_preset():
    """plant_check --fit's fit (fit_losses on the no-fan first pulse) keeps the radiating loss and
    gives twin/plants.py's ONION_RADIATING_PARAMS: stored to 4 significant digits (rounding under
    5e-4 relative), 1e-3 leaves the rest for another CPU's last bits (measured: within 1e-4); the
    RMSEs are docs/plants.md's 0.43 and 1.89 C."""
    fits, kept = fit_losses(**onion_fit_options())
    assert kept == "radiating"
    radiating = fits["radiating"]
    assert radiating.params == pytest.approx({k: ONION_RADIATING_PARAMS[k] for k in radiating.params}, rel=1e-3)
    assert ONION_RADIATING_PARAMS["emissivity"] == radiating.fixed["emissivity"]
    assert radiating.rmse_c == pytest.approx(0.43, abs=0.005) and fits["linear"].rmse_c == pytest.approx(1.89, abs=0.005)


@pytest.mark.slow  # 49 s of CPU: twin-fit's loss auto on a capture
def test_twin_fit_loss_auto_keeps_radiating_on_the_onionheater_pulse(capsys, hardware_logs):
    """The no-fan pulse's cooling rate per kelvin rises with temperature (docs/plants.md): the
    default two_node fit with --loss auto prints both fits and keeps the radiating one."""
    assert main([str(hardware_logs / ONION), "--loss", "auto", "--budget", "90", "--proof", "2"]) == 0  # the fit is tested
    out = capsys.readouterr().out
    found = re.search(r"^loss \(--loss auto\): linear RMSE (\S+) C, AIC (\S+); radiating RMSE (\S+) C, AIC (\S+): "
                      r"kept radiating \(lower AIC\)$", out, re.M)
    assert found, out
    linear_rmse, linear_aic, radiating_rmse, radiating_aic = map(float, found.groups())
    assert radiating_aic < linear_aic and radiating_rmse < linear_rmse
    assert "fit: two_node, radiating loss on segment 0" in out
    assert re.search(r"^  radiation: effective area \S+ cm\^2 \+- \S+ cm\^2, at emissivity 1 ", out, re.M)
    assert re.search(r"^  radiating_area_m2\s+\S+\s+\+- \S+\s+(poorly |not )?identified$", out, re.M)
    assert re.search(rf"RMSE {re.escape(f'{radiating_rmse:.2f}')} C, max \|residual\|", out)  # the kept fit's
    assert "M306 has no radiation term" in out and "M306 P" not in out  # Marlin's MPC is linear
    assert re.search(r"^\s+pid_Kp: [\d.]+$", out, re.M)


def test_twin_fit_loss_on_a_transfer_function_is_one_line(capsys, hardware_logs):
    with pytest.raises(SystemExit) as stop:
        main([str(hardware_logs / ONION), "--loss", "radiating", "--model", "fopdt"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err == "twin-fit: error: --loss radiating needs --model two_node or three_node: fopdt has no heat-loss term\n"
