"""Identification: the fitter recovers known plants from noisy synthetic data within its standard
errors, seed 001's FOPDT from its step response, the two-point and relay formulas on exact FOPDTs,
segment selection, and twin-fit end to end on real captures (through the hardware_logs
fixture: without the logs these skip locally and fail in CI)."""

import math
import re

import numpy as np
import pytest
import scipy.optimize
import scipy.signal

from tools.cli.fit import main
from tools.ident.fit import fit_model
from tools.ident.fopdt import CONTROL_DELAY_S, TWO_POINT_FRACTIONS, Fopdt, fopdt_equivalent, relay_fopdt, two_point_fopdt, ultimate_point
from tools.ident.response import zoh_response
from tools.ident.segments import MIN_HEATUP_S, NotFittable, default_segment, log_segments, split_heatups
from tools.logs import load_log
from tools.tuning.rules import amigo
from twin.plants import Lumped, Plant, TransferFunction, make_plant

AMBIENT_C = 22.0
NOISE_C = 0.3
SIGMAS = 3.0

ONION = "klipper_heattest_onionheater_heattest_200.csv"
CHES = "klippy_stats_chesleavens_cartesian_stm32f103.csv"
ENDER5 = "klippy_stats_icodextrin_ender5_creality427.csv"
QUICK = ("--budget", "90", "--proof", "2")  # the tune at a small budget where its verdict, not its search, is tested


def _staircase() -> tuple[np.ndarray, np.ndarray]:
    """0.5 s samples of an open-loop multi-level run: full power, off, half, a fifth."""
    t_s = np.arange(0.0, 600.0, 0.5)
    return t_s, np.select([t_s < 150, t_s < 300, t_s < 450], [1.0, 0.0, 0.5], 0.2)


def _noisy(spec, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t_s, duty = _staircase()
    clean_c = zoh_response(Plant("truth", spec, AMBIENT_C, AMBIENT_C), t_s, duty)
    return t_s, clean_c + np.random.default_rng(seed).normal(0.0, NOISE_C, len(t_s)), duty


# -- recovery from synthetic data -------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("model, spec, truth", [
    ("fopdt", TransferFunction(300.0, 1.0, lag1_s=80.0, delay_s=4.0),
     {"gain_c": 300.0, "time_constant_s": 80.0, "delay_s": 4.0}),
    ("sopdt", TransferFunction(300.0, 1.0, lag1_s=80.0, lag2_s=10.0, delay_s=3.0),
     {"gain_c": 300.0, "lag1_s": 80.0, "lag2_s": 10.0, "delay_s": 3.0}),
    ("two_node", Lumped(40.0, 12.0, 0.15, 0.12, 0.12),
     {"block_heat_capacity_j_k": 12.0, "sensor_responsiveness_per_s": 0.15, "ambient_xfer_w_k": 0.12}),
])
def test_recovers_known_parameters_within_their_standard_errors(model, spec, truth):
    t_s, temp_c, duty = _noisy(spec, seed=1)
    result = fit_model(model, t_s, temp_c, duty)  # ambient fitted too
    for name, value in {**truth, "ambient_c": AMBIENT_C}.items():
        error = result.std_errors[name]
        assert 0 < error < 0.05 * abs(value) + 0.5, (name, error)  # determined, and finite
        assert abs(result.params[name] - value) < SIGMAS * error, (name, result.params[name], error)
    assert result.rmse_c == pytest.approx(NOISE_C, rel=0.1)  # down to the noise: residuals are the noise
    assert result.n_samples == len(t_s) and result.max_abs_residual_c < 5 * NOISE_C
    # simulate() reproduces what the residuals were taken from
    np.testing.assert_allclose(result.simulate(t_s, duty) - temp_c, result.residuals_c, atol=1e-9)


@pytest.mark.slow


def test_three_node_reaches_the_noise_and_the_loss():
    """The cartridge and sensor lags can trade places (two near-equal optima): check what is unique."""
    spec = Lumped(40.0, 12.0, 0.15, 0.12, 0.12, cartridge_heat_capacity_j_k=2.0, cartridge_xfer_w_k=0.5)
    t_s, temp_c, duty = _noisy(spec, seed=2)
    result = fit_model("three_node", t_s, temp_c, duty, ambient_c=AMBIENT_C)
    assert result.rmse_c == pytest.approx(NOISE_C, rel=0.1)
    assert abs(result.params["ambient_xfer_w_k"] - 0.12) < SIGMAS * result.std_errors["ambient_xfer_w_k"]
    assert result.fixed == {"power_w": 40.0, "cartridge_heat_capacity_j_k": 2.0, "ambient_c": AMBIENT_C}


def test_seed001_fopdt_from_its_step_response():
    """Seed 001's nozzle, 0.196 e^-20.7s / (24 s + 1), stepped by 45 C of command (185 -> 230 C)."""
    step_c = 45.0
    plant = make_plant("seed001_fopdt", ambient_c=AMBIENT_C)
    u = step_c / plant.spec.input_full_scale
    t_s = np.arange(0.0, 300.0, 1.0)
    temp_c = zoh_response(plant, t_s, np.full(len(t_s), u))
    result = fit_model("fopdt", t_s, temp_c, np.full(len(t_s), u), ambient_c=AMBIENT_C)
    assert result.params["gain_c"] * u / step_c == pytest.approx(0.196, rel=1e-3)  # the twin scales by 2000
    assert result.params["time_constant_s"] == pytest.approx(24.0, rel=1e-3)
    assert result.params["delay_s"] == pytest.approx(20.7, abs=0.01)
    assert result.rmse_c < 1e-3
    # and the seed's own two-point method on the same response, per C of command
    quick = two_point_fopdt(t_s, temp_c, step_c)
    assert quick == pytest.approx((0.196, 24.0, 20.7), rel=0.01)


# -- quick estimates -------------------------------------------------------------------------------


@pytest.mark.parametrize("rise_c", [150.0, -80.0])  # a heat-up and a cool-down
def test_two_point_method_is_exact_on_a_fopdt(rise_c):
    gain, lag_s, delay_s, step = rise_c / 0.8, 60.0, 7.0, 0.8
    t_s = np.arange(0.0, 1000.0, 0.01)
    temp_c = 30.0 + gain * step * np.where(t_s > delay_s, 1.0 - np.exp(-(t_s - delay_s) / lag_s), 0.0)
    assert two_point_fopdt(t_s, temp_c, step) == pytest.approx((gain, lag_s, delay_s), rel=1e-4, abs=1e-3)
    assert TWO_POINT_FRACTIONS[0] == pytest.approx(0.28, abs=0.004)  # the seed's rounded 0.28


def test_relay_formula_inverts_the_ultimate_point():
    """Ku, Tu of a known FOPDT from scipy's frequency response; relay_fopdt gives the FOPDT back."""
    plant = Fopdt(320.0, 150.0, 6.0)
    num, den = [plant.gain_c], [plant.time_constant_s, 1.0]

    def phase(w):
        return np.angle(scipy.signal.freqresp((num, den), [w])[1][0]) - w * plant.delay_s + math.pi

    w_u = scipy.optimize.brentq(phase, 1e-4, math.pi / plant.delay_s)
    ku = 1.0 / abs(scipy.signal.freqresp((num, den), [w_u])[1][0])
    tu_s = 2.0 * math.pi / w_u
    assert ultimate_point(plant) == pytest.approx((ku, tu_s), rel=1e-6)
    assert relay_fopdt(ku, tu_s, plant.gain_c) == pytest.approx(plant, rel=1e-6)
    with pytest.raises(ValueError, match="needs K Ku > 1"):
        relay_fopdt(ku, tu_s, 0.5 / ku)


@pytest.mark.slow


def test_fopdt_equivalent_and_amigo_gains():
    fopdt = Fopdt(300.0, 80.0, 4.0)
    t_s, temp_c, duty = _noisy(TransferFunction(*fopdt[:1], 1.0, lag1_s=80.0, delay_s=4.0), seed=3)
    result = fit_model("fopdt", t_s, temp_c, duty, ambient_c=AMBIENT_C)
    assert fopdt_equivalent(result) == tuple(result.params[k] for k in ("gain_c", "time_constant_s", "delay_s"))
    # a first order behind a short sensor lag looks like a FOPDT with about that lag as dead time
    lag = fit_model("two_node", *_noisy(Lumped(40.0, 12.0, 0.5, 0.12, 0.12), seed=4), ambient_c=AMBIENT_C)
    k, tau, delay = fopdt_equivalent(lag)
    assert k == pytest.approx(40.0 / 0.12, rel=0.01) and tau == pytest.approx(100.0, rel=0.05) and 1.0 < delay < 2.5
    # AMIGO by hand: L = 4 + 0.45 s of loop delay
    big_l = 4.45
    kp = (0.2 + 0.45 * 80.0 / big_l) / 300.0
    ti = big_l * (0.4 * big_l + 0.8 * 80.0) / (big_l + 8.0)
    td = 0.5 * big_l * 80.0 / (0.3 * big_l + 80.0)
    gains = amigo(fopdt._replace(delay_s=fopdt.delay_s + CONTROL_DELAY_S))
    assert (gains.kp, gains.ki, gains.kd) == pytest.approx((255 * kp, 255 * kp / ti, 255 * kp * td))


def test_fit_model_refuses_bad_input():
    t_s, duty = _staircase()
    with pytest.raises(ValueError, match="unknown model"):
        fit_model("pid", t_s, t_s, duty)
    with pytest.raises(ValueError, match="differ in length"):
        fit_model("fopdt", t_s, t_s[:-1], duty)
    with pytest.raises(ValueError, match="no parameter"):
        fit_model("fopdt", t_s, t_s, duty, fixed={"power_w": 40.0})
    with pytest.raises(ValueError, match="within 0..1"):
        fit_model("fopdt", t_s, t_s, 2 * duty)


# -- segments --------------------------------------------------------------------------------------


def test_split_heatups_bridges_dips_and_cuts_at_a_target_change():
    t_s = np.arange(0.0, 900.0, 1.0)
    duty = np.where(t_s < 100, 1.0, 0.3)
    duty[50] = 0.98  # a one-line dip under full power: the same heat-up
    duty[(t_s >= 500) & (t_s < 520)] = 1.0  # a re-heat: a new segment
    target = np.where(t_s < 700, 200.0, 210.0)
    temp = 25.0 + np.cumsum(duty) * 0.1
    segments = split_heatups("", t_s, temp, duty, target_c=target)
    assert [(s.t_s[0], s.t_s[-1]) for s in segments] == [(0.0, 400.0), (500.0, 699.0)]
    assert segments[0].full_power_s == pytest.approx(99.0) and "in between (closed loop) 301 s" in segments[0].note
    short = duty.copy()
    short[(t_s >= 500) & (t_s < 520)] = 0.3
    short[500 : 500 + int(MIN_HEATUP_S) - 1] = 1.0  # too short to be a heat-up
    assert len(split_heatups("", t_s, temp, short)) == 1


def test_segments_of_real_logs(hardware_logs):
    onion = load_log(hardware_logs / ONION)
    heater, pulses = log_segments(onion)
    assert heater == "extruder" and len(pulses) == 2
    assert all("in between" not in s.note and "full power 11" in s.note for s in pulses)  # open loop
    heater, beds = log_segments(load_log(hardware_logs / CHES), "heater_bed")
    assert heater == "heater_bed" and "closed loop: the pwm Klipper last sent" in beds[0].note
    assert default_segment(beds) == 0 and beds[0].full_power_s > 60
    with pytest.raises(NotFittable, match="no heater 'extruder1'"):
        log_segments(load_log(hardware_logs / CHES), "extruder1")


# -- twin-fit on real captures ---------------------------------------------------------------------


def twin_fit(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def _rmse(out: str) -> float:
    return float(re.search(r"RMSE (\S+) C", out).group(1))


@pytest.mark.slow  # 43 s of CPU: twin-fit on a capture
def test_twin_fit_onionheater_two_node(capsys, hardware_logs):
    code, out, err = twin_fit(capsys, str(hardware_logs / ONION))
    assert code == 0, err
    assert "Klipper heattest (open loop)" in out and re.search(r"^\s+\*\s+0\s+89\.3\.\.", out, re.M)
    assert re.search(r"^  block_heat_capacity_j_k\s+\S+\s+\+- \S+\s+identified$", out, re.M)
    assert 1.0 < _rmse(out) < 4.0  # a few C: a two-node model misses the cartridge's lag
    assert re.search(r"^  Marlin:  M306 P40\.00 C[\d.]+ R[\d.]+ A[\d.]+ F[\d.]+$", out, re.M)
    # a Klipper heattest: the Klipper loop's gains, proven on the plants the log allows
    assert re.search(r"proven on the klipper loop|^keep your gains", out, re.M | re.I)  # twin-tune's answer
    assert re.search(r"^Klipper printer.cfg \(proven on the Klipper loop\):\n  \[extruder\]\n  control: pid\n  pid_Kp: [\d.]+\n"
                     r"  pid_Ki: [\d.]+\n  pid_Kd: [\d.]+$", out, re.M) and "M301" not in out


@pytest.mark.slow  # twin-fit on two heaters of a capture (the tune at QUICK: its verdict, not its search, is tested)
def test_twin_fit_klipper_stats_bed_and_extruder(capsys, hardware_logs):
    code, out, err = twin_fit(capsys, str(hardware_logs / CHES), "--heater", "heater_bed", *QUICK)
    assert code == 0, err
    assert "power_w 220 W assumed" in out and "the pwm Klipper last sent" in " ".join(out.split())
    assert _rmse(out) < 1.0
    # twin-tune's answer, as twin-tune prints it: the [heater_bed] section to paste, or keep your gains
    assert "\n  [heater_bed]\n  control: pid\n" in out or "keep your gains (Kp 54.03" in out
    assert "M306 P" not in out and "M304" not in out  # a klippy.log: Klipper's section, from the Klipper loop
    assert "the log's own gains: pid_Kp 54.027" in out
    code, out, err = twin_fit(capsys, str(hardware_logs / ENDER5), "--model", "fopdt", "--segment", "0", *QUICK)
    assert code == 0, err
    assert re.search(r"^  delay_s\s+\S+\s+(\+- \S+|at its bound)\s+(poorly |not )?identified$", out, re.M)
    assert _rmse(out) < 3.0
    # twin-tune's answer: the printer's gains are its PID_CALIBRATE's (Tu 36.9 s), and no plant fitted to the 1 Hz
    # Stats relays there (12-17 s; the refits that do miss its Ku): keep them (issue 38 item 5)
    assert "answer: keep your gains (Kp 24.83" in out, out[-1500:]
    assert "no fitted plant relays as your PID_CALIBRATE did (Tu 36.9 s, Ku 41.4)" in out


def test_twin_fit_marlin_m303_trace(capsys, hardware_logs):
    """The full-power heat-up of #8081 (2 s status lines) fitted with its printed relay cycle, and that
    cycle through the fitted gain."""
    code, out, err = twin_fit(capsys, str(hardware_logs / "m303_hotend_S250_trace_marlin8081_partial.txt"),
                              "--model", "fopdt", "--fit-only")
    assert code == 0, err
    assert "* 0 lines 9..35, 0.0..52.0 s, 27 samples: full power 52 s; 2 s per status line" in " ".join(out.split())
    assert "fit: fopdt on segment 0 (relay results and status trace)" in out
    assert "line 57: target 250 C, on 1.000 off 0.685: Tu 21.97 s, min 247.60 max 252.29" in out  # bias 206
    trace_rmse = float(re.search(r"^  trace: RMSE (\S+) C", out, re.M).group(1))
    assert trace_rmse < 1.5
    assert re.search(r"the log's last relay cycle, Ku 0\.1023 duty per C, Tu 21\.97 s, through the fitted gain: "
                     r"time constant \S+ s, dead time \S+ s", " ".join(out.split()))


@pytest.mark.parametrize("name, why", [
    ("m303_hotend_C1_degenerate_marlin6316.txt", ": not usable for fitting: autotune output with 1 relay cycles and "
                                                 "no status trace to fit; 0 printed cycles"),
    ("m303_hotend_repetier_davinci356.txt", ": not usable for fitting: .*Repetier's relay"),
    ("README.md", ":3: not a log of a known kind"),
    ("rrf_m303_fopdt_models_prusa_mk3s_duet3.txt", r":\d+: RepRapFirmware heater model results"),
])
def test_twin_fit_refuses_what_it_cannot_fit(capsys, name, why, hardware_logs):
    code, out, err = twin_fit(capsys, str(hardware_logs / name))
    assert code == 2 and out == ""
    assert re.fullmatch(rf"twin-fit: error: \S*/{re.escape(name)}{why}.*\n", err, re.S), err
    assert "Traceback" not in err


def test_twin_fit_errors_name_file_and_line(capsys, tmp_path, hardware_logs):
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,temp_c,duty\n0,25,0\n1,26,x\n")
    assert twin_fit(capsys, str(bad)) == (2, "", f"twin-fit: error: {bad}:3: duty (0..1; name the column duty_pct "
                                                  "for percent): 'x' is not a number\n")
    code, _, err = twin_fit(capsys, str(tmp_path / "missing.csv"))
    assert code == 2 and err == f"twin-fit: error: {tmp_path / 'missing.csv'}: No such file or directory\n"
    code, _, err = twin_fit(capsys, str(hardware_logs / ONION), "--segment", "9")
    assert code == 2 and "--segment 9: the segments are 0..1" in err


@pytest.mark.parametrize("flags, flag", [(["--heater", "chamber"], "--heater"), (["--ambient", "nan"], "--ambient"),
                                         (["--ambient", "inf"], "--ambient"), (["--power-w", "-40"], "--power-w"),
                                         (["--power-w", "nan"], "--power-w")])
def test_twin_fit_bad_flag_one_line_naming_it(flags, flag, capsys, hardware_logs):
    with pytest.raises(SystemExit) as stop:
        main([str(hardware_logs / ONION), *flags])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"twin-fit: error: argument {flag}:") and len(err.strip().splitlines()) == 1


def test_twin_fit_help_has_examples(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "examples:\n  twin-fit " in out and "see above" not in out
