"""The registry of log readers (tools/logs/registry.py, detect.py), the streamed CSV readers, the
result-lines-only copy of an M303 capture and the cycles whose heater a capture does not say."""

import numpy as np
import pytest

from tools.logs import LogError, M303Log, PlainLog, load_log, parse_m303, results_only
from tools.logs import detect, registry
from tools.logs.registry import HEAD_LINES, Head, Reader

ENDER = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"
PRUSA_BED = "m303_bed_and_hotend_octoprint_calibrationcompanion26_partial.txt"


def test_a_new_format_is_a_reader_and_its_registration(tmp_path, monkeypatch):
    """A format this package does not know: one Reader, one entry in READERS, and load_log reads it."""
    path = tmp_path / "myfw.log"
    path.write_text("myfw v1\n0 25.0\n1 26.5\n")

    def parse(p):
        rows = [line.split() for line in p.read_text().splitlines()[1:]]
        t, temp = np.array(rows, dtype=float).T
        return PlainLog(p, t, temp, np.ones(len(t)), False)

    with pytest.raises(LogError, match="not a log of a known kind"):
        load_log(path)
    reader = Reader("my firmware's log", lambda head: head.first.startswith("myfw "), parse)
    monkeypatch.setattr(detect, "READERS", (reader, *detect.READERS))
    log = load_log(path)
    assert isinstance(log, PlainLog) and log.temp_c.tolist() == [25.0, 26.5]


def test_the_error_lists_every_registered_kind(tmp_path):
    path = tmp_path / "x.txt"
    path.write_text("hello\n")
    with pytest.raises(LogError) as error:
        load_log(path)
    names = [r.name for r in detect.READERS if r.name != "RepRapFirmware heater models"]
    assert all(name in str(error.value) for name in names) and str(error.value).startswith(f"{path}:1:")


def test_detection_reads_the_head_only(tmp_path):
    """A plain CSV whose line past the head is not even UTF-8: detection never reads it; the reader
    then reports it with its line number."""
    path = tmp_path / "long.csv"
    rows = "".join(f"{i},25.0,0.5\n" for i in range(HEAD_LINES + 10))
    path.write_bytes(b"t_s,temp_c,duty\n" + rows.encode() + b"\xff\xfe,1,1\n")
    assert len(Head.of(path).lines) == HEAD_LINES
    with pytest.raises(LogError, match=rf":{HEAD_LINES + 12}: not UTF-8 text"):
        load_log(path)


def test_plain_csv_is_streamed_into_arrays(tmp_path):
    """200,000 rows read row by row give the same numbers as numpy's own reader."""
    path = tmp_path / "big.csv"
    t = np.arange(200_000) * 0.1
    temp = 25.0 + np.round(np.sin(t / 50.0) * 40.0, 2)
    duty = (t % 60 < 20).astype(float)
    path.write_text("t_s,temp_c,duty\n" + "".join(f"{a:.1f},{b:.2f},{c:g}\n" for a, b, c in zip(t, temp, duty)))
    log = load_log(path)
    expected = np.loadtxt(path, delimiter=",", skiprows=1)
    assert isinstance(log, PlainLog) and len(log.t_s) == 200_000
    np.testing.assert_array_equal(np.column_stack((log.t_s, log.temp_c, log.duty)), expected)


def test_plain_csv_time_must_increase_row_by_row(tmp_path):
    path = tmp_path / "back.csv"
    path.write_text("t_s,temp_c,duty\n0,25,0\n1,26,0\n1,27,0\n")
    with pytest.raises(LogError, match=r":4: time 1 s does not increase \(previous sample: 1 s\)"):
        load_log(path)


def test_results_only_keeps_every_line_but_the_status_reports(tmp_path, hardware_logs):
    text = (hardware_logs / ENDER).read_text()
    alone = results_only(text)
    dropped = set(text.splitlines()) - set(alone.splitlines())
    assert dropped and all(line.lstrip().startswith("T:") for line in dropped)
    path = tmp_path / ENDER
    path.write_text(alone)
    log, full = parse_m303(path), load_log(hardware_logs / ENDER)
    assert isinstance(full, M303Log) and not log.status and log.idle_readings_c == []
    assert [(c.bias, c.tu_s, c.min_c, c.max_c) for c in log.cycles] == \
        [(c.bias, c.tu_s, c.min_c, c.max_c) for c in full.cycles]


def test_cycles_nothing_attributes_are_marked_unknown(tmp_path, hardware_logs):
    """The Prusa bed run's cycles follow one-heater B: reports; without those lines (and with no
    M303 E-1 line in the excerpt) nothing says which heater they tune: "?", counted for either."""
    log = load_log(hardware_logs / PRUSA_BED)
    assert {c.heater for c in log.cycles} == {"B"}
    path = tmp_path / PRUSA_BED
    path.write_text(results_only((hardware_logs / PRUSA_BED).read_text()))
    alone = parse_m303(path)
    assert {c.heater for c in alone.cycles} == {"?"}
    assert alone.cycles_of("B") == alone.cycles_of("T") == alone.cycles


USER_MODULE = '''
import numpy as np
from tools.logs import PlainLog
from tools.logs.registry import Reader

def parse(path):
    rows = [line.split() for line in path.read_text().splitlines()[1:]]
    t, temp = np.array(rows, dtype=float).T
    return PlainLog(path, t, temp, np.ones(len(t)), False)

READER = Reader("my firmware's log", lambda head: head.first.startswith("myfw "), parse)
NOT_A_READER = 42
'''


@pytest.fixture
def user_reader(tmp_path, monkeypatch):
    """A reader in a module of the user's own (myfw_reader.py, on the path), and a log only it reads."""
    (tmp_path / "myfw_reader.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    log = tmp_path / "run.myfw"
    log.write_text("myfw v1\n0 25.0\n1 26.5\n")
    return log


def test_every_built_in_log_names_its_format(hardware_logs):
    """The reader that read a log names it on the log: the CLIs print and choose their checks by it."""
    assert load_log(hardware_logs / ENDER).format == "M303 console text (Marlin, Repetier)"
    assert load_log(hardware_logs / PRUSA_BED).format == detect.m303.READER.name
    assert load_log(hardware_logs / "klipper_pid_calibrate_results_collection.txt").format == \
        "Klipper PID_CALIBRATE results"
    assert detect.format_names() == [r.name for r in detect.READERS if r.name != "RepRapFirmware heater models"]


def test_a_users_reader_named_in_the_environment(user_reader, monkeypatch):
    monkeypatch.setenv(registry.READERS_ENV, "myfw_reader:READER")
    log = load_log(user_reader)
    assert log.format == "my firmware's log" and log.temp_c.tolist() == [25.0, 26.5]
    assert detect.format_names()[0] == "my firmware's log"


def test_a_users_reader_from_an_installed_entry_point(user_reader, tmp_path, monkeypatch):
    """A package that declares its reader in the heater_twin.log_readers group: no environment, no flag."""
    registry._entry_point_readers.cache_clear()
    with pytest.raises(LogError, match="not a log of a known kind"):
        load_log(user_reader)
    info = tmp_path / "myfw_reader-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: myfw-reader\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\nmyfw = myfw_reader:READER\n")
    registry._entry_point_readers.cache_clear()
    try:
        assert load_log(user_reader).format == "my firmware's log"
    finally:
        registry._entry_point_readers.cache_clear()


@pytest.mark.parametrize("spec, says", [
    ("myfw_reader:NOT_A_READER", "HEATER_TWIN_READERS=myfw_reader:NOT_A_READER: a int, not a tools.logs.registry.Reader"),
    ("myfw_reader:MISSING", "HEATER_TWIN_READERS=myfw_reader:MISSING: .*MISSING"),
    ("no_such_module_here:READER", "HEATER_TWIN_READERS=no_such_module_here:READER: No module named"),
    ("myfw_reader:READER,myfw_reader:READER", "two log readers name the format \"my firmware's log\""),
])
def test_a_bad_user_reader_is_one_line(user_reader, monkeypatch, spec, says):
    monkeypatch.setenv(registry.READERS_ENV, spec)
    with pytest.raises(ValueError, match=says):
        load_log(user_reader)


def test_a_reader_must_return_a_log(tmp_path, monkeypatch):
    path = tmp_path / "x.myfw"
    path.write_text("myfw v1\n")
    reader = Reader("my firmware's log", lambda head: head.first.startswith("myfw "), lambda p: [1, 2])
    monkeypatch.setattr(detect, "READERS", (reader, *detect.READERS))
    with pytest.raises(LogError, match=r":1: the my firmware's log reader returned a list, not one of"):
        load_log(path)


def test_twin_compare_names_a_format_it_has_no_check_for(user_reader, monkeypatch, capsys):
    from tools.cli import compare

    monkeypatch.setenv(registry.READERS_ENV, "myfw_reader:READER")
    assert compare.main([str(user_reader)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"twin-compare: error: {user_reader}: not usable: no check for its format (my firmware's log): "
                   "the checks take Klipper Stats CSV, klippy.log, Klipper heattest (open loop), M303 console text "
                   "(Marlin, Repetier)")
