"""fit_log (tools/ident/log_fit.py) and twin-fit on every capture: an answer, or a one-line reason and a
non-zero status; a degenerate fit is no plant the answer stands on; one plant for twin-fit and twin-tune."""

import re

import numpy as np
import pytest

from tools.cli.fit import main
from tools.ident.fit import RADIATING_BOUNDS_M2, RADIATING_PARAM, RADIATING_SPAN_C
from tools.ident.log_fit import MAX_FIT_SAMPLES, LogFitOptions, fit_log, radiating_span_c
from tools.ident.segments import Segment
from tools.logs import load_log, results_only
from tools.tuning.defaults import EXIT_NO_MODEL
from tools.tuning.evaluate import full_power_time_s
from twin.linear import SENSOR

ENDER = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"
PRUSA_BED = "m303_bed_and_hotend_octoprint_calibrationcompanion26_partial.txt"
GAINS_RE = re.compile(r"M30[14] (E0 )?P|pid_Kp")


def _twin_fit(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
@pytest.mark.each_hardware_log("*", exclude=["README.md"])
def test_twin_fit_on_every_capture(capsys, hardware_log):
    """Every capture in hardware_logs: an answer (twin-tune's, here at --budget 40 --proof 1: new gains or
    "keep your gains" and why; exit 0, or 1 where no gains are known and nothing safe was found), or refused
    with one line on stderr: 2 a log that cannot be fitted, 3 neither a plant it allows nor gains; never a
    traceback; a refused one prints no gains."""
    code, out, err = _twin_fit(capsys, str(hardware_log), "--budget", "40", "--proof", "1")
    assert "Traceback" not in err
    if code in (0, 1):
        assert re.search(r"^answer: (new gains \(|keep )", out, re.M) and err == "", out
    else:
        assert code in (2, EXIT_NO_MODEL) and len(err.strip().splitlines()) == 1 and not GAINS_RE.search(out)


def test_a_log_without_a_heater_step_is_refused(capsys, tmp_path):
    """600 rows of t,25,0: nothing to identify; before, a 'fit' with ready-to-paste gains and exit 0."""
    flat = tmp_path / "flat.csv"
    flat.write_text("t,temp,duty\n" + "".join(f"{i},25,0\n" for i in range(600)))
    code, out, err = _twin_fit(capsys, str(flat))
    assert code == 2 and out == "" and "no heater step: the duty stays at 0 throughout" in err


@pytest.mark.slow
def test_a_degenerate_fit_is_no_plant_the_answer_stands_on(capsys, hardware_logs):
    """two_node on the Prusa bed's relay trace identifies neither its capacity nor its sensor lag: reported,
    never a plant the log allows; the answer comes from the plants it does allow. With --fit-only there is
    no other plant: no settings, exit 3, one line."""
    argv = [str(hardware_logs / PRUSA_BED), "--heater", "heater_bed", "--model", "two_node"]
    code, out, err = _twin_fit(capsys, *argv, "--fit-only")
    assert code == EXIT_NO_MODEL and not GAINS_RE.search(out)
    assert err.startswith("twin-fit:") and "degenerate fit, no settings" in err and len(err.splitlines()) == 1
    assert "not identified" in out  # the parameter table says which
    code, out, err = _twin_fit(capsys, *argv, "--budget", "90", "--proof", "2")
    assert code == 0, err
    assert "the two_node fit is degenerate (the data identify none of two_node's lags" in " ".join(out.split())
    assert re.search(r"^  dropped two_node: ", out, re.M) and not re.search(r"^  member two_node:", out, re.M)
    assert re.search(r"^answer: (new gains \(|keep your gains)", out, re.M)


@pytest.mark.slow
def test_the_m303_plant_holds_its_target_at_its_ambient(hardware_logs):
    """twin-tune said "full power holds 69.99 C" where twin-fit said a 524 C rise: it refitted the
    ambient (about 195 C, a relay trace cannot tell) and ran the spec at 25 C. The fit now holds the
    ambient (the idle bed's 30 C) and carries it: full power at that ambient holds the rise twin-fit
    prints, far above the target."""
    result = fit_log(load_log(hardware_logs / ENDER)).result
    assert result.ambient_c == 30.0
    spec = result.spec()
    lti = spec.lti(spec.conditions(0.0, 0.0, result.ambient_c, result.ambient_c))
    rise_c = float(-(lti.c[SENSOR] @ np.linalg.solve(lti.a, lti.b)))
    assert rise_c == pytest.approx(result.derived()["rise_at_full_power_c"], rel=1e-9)
    assert result.ambient_c + rise_c > 400.0
    assert 0.0 < full_power_time_s(spec, result.ambient_c, 210.0) < 120.0


@pytest.mark.slow
def test_result_lines_alone_are_fitted_with_fopdt(capsys, tmp_path, hardware_logs):
    copy = tmp_path / ENDER
    copy.write_text(results_only((hardware_logs / ENDER).read_text()))
    code, out, err = _twin_fit(capsys, str(copy))
    assert code == 0, err
    assert "fit: fopdt on the printed cycles (relay results)" in out
    assert "ambient 25 C: a room, assumed" in " ".join(out.split())  # the idle bed's lines went with the status
    assert re.search(r"^  ambient_c 15\.\.35: a room", out, re.M)  # and it is in what the data cannot tell


def test_a_long_segment_is_decimated_keeping_its_heat():
    t_s = np.arange(0.0, 6000.0, 0.1)
    duty = ((t_s % 7.3) < 2.0).astype(float)
    seg = Segment("x", t_s, 25.0 + t_s / 100.0, duty)
    small = seg.decimated(MAX_FIT_SAMPLES)
    assert len(small.t_s) <= MAX_FIT_SAMPLES + 1 and small.t_s[-1] == t_s[-1] and "decimated from 60000" in small.note
    energy = np.sum(seg.duty[:-1] * np.diff(seg.t_s))
    assert np.sum(small.duty[:-1] * np.diff(small.t_s)) == pytest.approx(energy, rel=1e-12)


def test_fit_cycles_needs_an_m303_capture(hardware_logs):
    with pytest.raises(ValueError, match="--fit-cycles needs an M303 capture"):
        fit_log(load_log(hardware_logs / "klipper_heattest_onionheater_heattest_200.csv"),
                LogFitOptions(fit_cycles=2))


S250 = "m303_hotend_S250_trace_marlin8081_partial.txt"
ARTILLERY_BED = "m303_bed_artillery_genius_pro_S60_configs641.txt"


def test_loss_radiating_is_fitted_on_an_m303_capture_that_spans_it(hardware_logs):
    """The 250 C capture (its status trace 24..117 C, its relay at 250 C): --loss radiating fits the area with
    its relay cycles and trace, no worse than the linear fit it nests (it starts from it); --loss auto fits
    both and says so; neither is the linear fit passed off under another name."""
    log = load_log(hardware_logs / S250)
    assert radiating_span_c(fit_log(log).segment, 250.0) >= RADIATING_SPAN_C
    linear = fit_log(log, LogFitOptions())
    radiating = fit_log(log, LogFitOptions(loss="radiating"))
    assert linear.result.loss == "linear" and RADIATING_PARAM not in linear.result.params
    assert radiating.result.loss == "radiating" and radiating.result.values["emissivity"] == 1.0
    assert RADIATING_BOUNDS_M2[0] <= radiating.result.params[RADIATING_PARAM] <= RADIATING_BOUNDS_M2[1]
    assert radiating.result.rmse_c <= linear.result.rmse_c + 1e-3
    auto = fit_log(log, LogFitOptions(loss="auto"))
    assert [line.split()[0] for line in auto.compared] == ["linear", "radiating"]


@pytest.mark.parametrize("name, loss, why", [
    (ENDER, "radiating", "its status trace and relay target span 8 C"),
    (ARTILLERY_BED, "auto", "it has no status trace, and its printed cycles sit at one temperature")])
def test_loss_radiating_is_refused_where_an_m303_capture_cannot_tell(capsys, hardware_logs, name, loss, why):
    """An M303 capture spanning less than RADIATING_SPAN_C: --loss radiating or auto is refused in one line
    naming the option and why (exit 2), never silently fitted linear."""
    code, out, err = _twin_fit(capsys, str(hardware_logs / name), "--fit-only", "--loss", loss)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert f"--loss {loss}: this M303 capture cannot tell a radiating loss from a linear one: {why}" in err
