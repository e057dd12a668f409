"""An M303 capture as users paste it, without its M303 line: the heater and the relay's target found in
the data (tools/logs/m303.py reads which heater a run's lines say, tools/ident/relay_points.py relay_heater
decides where none does, tools/ident/relay_trace.py relay_target_c places the target), as twin-fit reports
them and tunes at them."""

import re

import numpy as np
import pytest

from tools.cli.fit import main
from tools.ident.log_fit import fit_log
from tools.ident.relay_points import BED_MAX_TARGET_C, marlin_points, relay_heater
from tools.ident.relay_trace import relay_target_c
from tools.ident.segments import NotFittable
from tools.logs import M303Log, load_log, parse_m303

ARTILLERY_BED = "m303_bed_artillery_genius_pro_S60_configs641.txt"
COMMAND_RE = re.compile(r"\bM303\b([^\n]*)")


def pasted(text: str) -> str:
    """The capture without the lines that hold the M303 command (comment lines that name it go too)."""
    return "".join(line for line in text.splitlines(keepends=True) if "M303" not in line)


def write(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.slow
@pytest.mark.each_hardware_log("m303_*.txt")
def test_a_capture_without_its_command_gives_the_heater_and_target_it_states(tmp_path, hardware_log):
    """Every shared M303 capture, fitted as posted and without its M303 line(s): the same heater and relay
    target; where the capture states them (its command, before the fitted cycles), those; a capture that
    cannot be fitted gives the same one-line reason either way, never a heater or a target."""
    text = hardware_log.read_text()
    path = write(tmp_path, hardware_log.name, pasted(text))
    log = load_log(path)
    assert isinstance(log, M303Log) and log.commands == []
    try:
        full = fit_log(load_log(hardware_log))
    except NotFittable as refused:
        with pytest.raises(NotFittable) as also:
            fit_log(log)
        assert str(also.value) == str(refused)
        return
    found = fit_log(log)
    assert (found.heater, found.target_c) == (full.heater, full.target_c)
    assert found.target_source.startswith("found in the data") and found.target_c == round(found.target_c)
    assert f"relay target {found.target_c:g} C: found in the data" in "\n".join(found.notes)
    if full.target_source == "from the M303 command":  # the capture states the target and the heater
        command = next(c for _, c in load_log(hardware_log).commands if c.startswith("M303"))
        assert full.target_c == float(re.search(r"\bS(\d+)", command)[1])
        assert full.heater == ("heater_bed" if re.search(r"\bE-1\b", command) else "extruder")


@pytest.mark.slow
def test_twin_fit_tunes_a_pasted_bed_capture_as_a_bed_at_its_target(capsys, tmp_path, hardware_logs):
    """The Artillery bed's lines without 'M303 E-1 C8 S60': twin-fit took it for a hotend and tuned it at
    210 C (M301). Now: the bed (its reports show the bed alone powered), 60 C, and M304 gains."""
    path = write(tmp_path, "pasted.txt", pasted((hardware_logs / ARTILLERY_BED).read_text()))
    code = main([str(path)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "M303 console text (Marlin, Repetier); heater heater_bed" in out
    assert "heater_bed: line 4 reports both heaters, the bed alone powered" in out
    assert re.search(r"relay target 60 C: found in the data: within 59\.82\.\.60\.21 C", out)
    # a bed on the Marlin loop: M304 where new gains beat the capture's, else keep them; never an M301
    assert ("M304 P" in out or "keep your gains (Kp 22.17 Ki 1.36 Kd 241.3" in out) and "M301 P" not in out


def test_each_cycle_is_fitted_at_the_levels_of_the_bias_line_before_it(tmp_path, hardware_logs):
    """Marlin moves the bias every cycle (34, 24, 21, 20, ... on the Artillery bed): each printed cycle ran at
    the levels of the bias line before it, (bias + d) >> 1 on, (bias - d) >> 1 off, pasted or not."""
    path = write(tmp_path, "pasted.txt", pasted((hardware_logs / ARTILLERY_BED).read_text()))
    log = load_log(path)
    assert [c.bias for c in log.cycles] == [34, 24, 21, 20, 20, 20, 20, 20]
    points = marlin_points(log, "heater_bed")
    assert [round(p.relay.on_duty * 127) for p in points] == [24, 21, 20, 20, 20, 20]
    assert all(p.relay.off_duty == 0 and p.relay.target_c == 60.0 for p in points)


# --- the rules, on small captures ------------------------------------------------------------------

HOTEND_120 = """\
 bias: 60 d: 60 min: 117.10 max: 123.40 T:119.20 /0.00 B:24.10 /0.00 @:60 B@:0
 bias: 58 d: 58 min: 117.30 max: 123.10 T:121.80 /0.00 B:24.20 /0.00 @:0 B@:0
 bias: 57 d: 57 min: 117.40 max: 122.90 Ku: 25.00 Tu: 20.00
 Classic PID
 Kp: 15.00 Ki: 1.50 Kd: 37.50
"""


def test_a_report_of_both_heaters_with_one_powered_names_the_heater(tmp_path):
    """M303 switches every other heater off: the powered one (@ here) is tuned, though 120 C is a bed's
    temperature. Without the reports, nothing says which, and the relay's target decides: a bed."""
    log = parse_m303(write(tmp_path, "a.txt", HOTEND_120))
    assert {c.heater for c in log.cycles} == {"T"} and [s.temp_c for s in log.status] == [119.2, 121.8]
    assert relay_heater(log) == ("extruder", "line 1 reports both heaters, the hotend alone powered "
                                             "(M303 switches the others off)")
    bare = parse_m303(write(tmp_path, "b.txt", re.sub(r" T:\S+ /\S+ B:.*", "", HOTEND_120)))
    assert {c.heater for c in bare.cycles} == {"?"}
    heater, why = relay_heater(bare)
    assert heater == "heater_bed" and f"{BED_MAX_TARGET_C:g} C" in why and "120 C" in why


def test_reports_of_both_heaters_wait_for_the_line_that_says_which(tmp_path):
    """Before a line says which heater, a report of both with neither powered is held back, then read as the
    bed's once B@ shows the bed alone powered (and the idle hotend's reading kept as the room's)."""
    text = (" T:24.50 /0.00 B:60.40 /0.00 @:0 B@:0\n"
            " bias: 40 d: 40 min: 59.60 max: 60.50 T:24.60 /0.00 B:59.70 /0.00 @:0 B@:40\n")
    log = parse_m303(write(tmp_path, "a.txt", text))
    assert [(s.heater, s.temp_c, s.power) for s in log.status] == [("B", 60.4, 0), ("B", 59.7, 40)]
    assert log.idle_readings_c == [24.5, 24.6] and [c.heater for c in log.cycles] == ["B"]


@pytest.mark.parametrize("line, heater", [("#define DEFAULT_bedKp 22.17", "B"), ("#define DEFAULT_Kp 15.00", "T"),
                                          (" No overshoot", "B")])
def test_marlins_own_words_name_the_heater(tmp_path, line, heater):
    """Marlin prints the bed's result as DEFAULT_bedK* and (2.x) tunes it by the 'No overshoot' rule."""
    text = " bias: 40 d: 40 min: 99.60 max: 100.50\n bias: 38 d: 38 min: 99.70 max: 100.40 Ku: 90.0 Tu: 30.0\n"
    log = parse_m303(write(tmp_path, "a.txt", text + line + "\n"))
    assert {c.heater for c in log.cycles} == {heater} and log.runs[0].evidence.startswith("line 3")


def test_each_run_of_a_capture_has_its_own_heater_and_target(tmp_path):
    """Two runs pasted without their commands, split at 'PID Autotune start': the hotend's reports say nothing
    of the bed run after it, and each run's target comes from its own cycles."""
    text = (" bias: 60 d: 60 min: 205.10 max: 214.90 T:209.00 /0.00 B:24.10 /0.00 @:60 B@:0\n"
            " bias: 58 d: 58 min: 205.40 max: 214.20 Ku: 25.00 Tu: 20.00\n"
            "PID Autotune finished! Put the last Kp, Ki and Kd constants from below into Configuration.h\n"
            "PID Autotune start\n"
            " bias: 40 d: 40 min: 59.60 max: 60.50\n"
            " bias: 38 d: 38 min: 59.70 max: 60.40 Ku: 90.00 Tu: 30.00\n")
    log = parse_m303(write(tmp_path, "a.txt", text))
    assert [c.heater for c in log.cycles] == ["T", "T", "?", "?"] and [r.line_no for r in log.runs] == [1, 4]
    assert relay_target_c(log, "T", 1)[0] == 210.0 and relay_target_c(log, "B", 5)[0] == 60.0


def test_the_target_is_a_whole_degree_every_cycle_holds(tmp_path):
    """Marlin resets min and max to the target at each switch: every printed cycle's min..max holds it. The
    middle of the common range (203.98..208.01 here) is 206.0; the status trace's switches, where there are
    some, pick within it, and a switch estimate outside it is brought back to its edge."""
    text = (" bias: 61 d: 61 min: 203.98 max: 216.95\n bias: 56 d: 56 min: 201.50 max: 208.01\n"
            " bias: 55 d: 55 min: 202.87 max: 211.91 Ku: 17.41 Tu: 18.16\n")
    log = parse_m303(write(tmp_path, "a.txt", text))
    target_c, source = relay_target_c(log, "T", 1)
    assert target_c == 206.0 and "within 203.98..208.01 C" in source and source.endswith("its middle")
    switched = (np.array([206.6, 208.0]), np.array([True, False]))  # off between readings 206.6 and 208.0
    target_c, source = relay_target_c(log, "T", 1, switched)
    assert target_c == 207.0 and source.endswith("the status trace's switches")
    far = (np.array([208.0, 212.0]), np.array([True, False]))  # 210 by the switches: outside the range
    assert relay_target_c(log, "T", 1, far)[0] == 208.0
    assert relay_target_c(log, "T", 1)[0] == relay_target_c(log, "B", 1)[0]  # "?" cycles count for either
