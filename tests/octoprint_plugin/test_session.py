"""The plugin's session without a server: what it sends, what it reads of Marlin's replies, and the one
line it says when something goes wrong. The printer is a recorder that the test answers with the lines
twin-serial prints (docs/serial.md); the tune itself runs in tests/octoprint_plugin/test_tab.py."""

from __future__ import annotations

import threading
import time

import pytest

from tests.helpers.octoprint_server import require_octoprint

require_octoprint()

from octoprint_heater_twin import session as tab  # noqa: E402  (OctoPrint first: the package imports it)
from octoprint_heater_twin import tuner  # noqa: E402
from octoprint_heater_twin import check  # noqa: E402
from octoprint_heater_twin.console import Gains, autotune_command, gains_in, is_cycle_end, is_text, reading  # noqa: E402

TIMEOUT_S = 3600.0  # a test's autotune never times out unless it says so
TUNE_TIMEOUT_S = 1800.0  # a hang guard for a real twin-tune (well under a minute when quiet)
M303_CAPTURE = "m303_hotend_ender3v3se_creality_stock_navaismo16_partial.txt"  # a hotend's M303 with its trace
M503 = ["echo:; Hotend PID:", "echo:  M301 P19.96 I2.06 D48.23", "echo:; Bed PID:",
        "echo:  M304 P86.92 I10.40 D484.20", "ok"]
ANSWER = {"verdict": "new gains", "why": "beats yours on every member", "heater": "extruder", "target_c": 210.0,
          "loop": "marlin", "current": {"kp": 19.96, "ki": 2.06, "kd": 48.23, "source": "M503"},
          "answer": {"kp": 22.37, "ki": 1.873, "kd": 66.81}, "commands": ["M301 E0 P22.37 I1.873 D66.81", "M500"],
          "members": [], "proof": [], "plot": None}


class Printer:
    """Records what the session queues; refuses with ``refused`` when set."""

    def __init__(self):
        self.sent: list[str] = []
        self.refused: str | None = None

    def refusal(self) -> str | None:
        return self.refused

    def send(self, commands: list[str]) -> None:
        self.sent += commands


@pytest.fixture
def printer():
    return Printer()


@pytest.fixture
def session(tmp_path, printer):
    published: list[dict] = []
    made = tab.Session(tmp_path / "runs", printer, published.append)
    made.published = published  # type: ignore[attr-defined]
    yield made
    made._cancel_timer()


def until(test, timeout_s: float = 300.0) -> bool:
    """Whether ``test()`` comes true within ``timeout_s`` (the session's timer and tune run on threads)."""
    deadline = time.monotonic() + timeout_s
    while not test() and time.monotonic() < deadline:
        time.sleep(0.01)
    return test()


def reply(session: tab.Session, *lines: str) -> None:
    for line in lines:
        session.on_received(line + "\n")


def test_the_gains_are_read_from_marlins_lines():
    assert gains_in("echo:  M301 P19.96 I2.06 D48.23", "extruder") == Gains(19.96, 2.06, 48.23)
    assert gains_in("echo:  M301 E0 P22.2 I1.08 D114 C100", "extruder") == Gains(22.2, 1.08, 114.0)
    assert gains_in("echo:  M304 P86.92 I10.40 D484.20", "extruder") is None
    assert gains_in("M304 P86.92 I10.40 D484.20", "heater_bed") == Gains(86.92, 10.4, 484.2)
    assert autotune_command("extruder", 210.0, 8) == "M303 E0 S210 C8"
    assert autotune_command("heater_bed", 60.5, 5) == "M303 E-1 S60.5 C5"


def test_gains_hold_when_m503_prints_them_to_its_two_decimals():
    sent = Gains(22.37, 1.873, 66.81)
    assert sent.holds(Gains(22.37, 1.87, 66.81))
    assert not sent.holds(Gains(22.37, 1.88, 66.81))
    assert not sent.holds(Gains(19.96, 2.06, 48.23))


def test_the_tuner_is_called_as_its_contract_says(tmp_path):
    args = tuner.command(tmp_path, "heater_bed", Gains(86.92, 10.4, 484.2), plot=True)
    assert args[0].endswith("twin-tune")
    assert args[1:] == ["--from-log", str(tmp_path / "capture.txt"), "--heater", "heater_bed",
                        "--current-gains", "86.92,10.4,484.2", "--json", str(tmp_path / "answer.json"),
                        "--progress", "lines", "--plot", str(tmp_path / "plot.png"), "--plot-compact",
                        str(tmp_path / "plot-tab.png")]
    assert "--current-gains" not in tuner.command(tmp_path, "extruder", None, plot=True)
    assert tuner.command(tmp_path, "extruder", None, plot=False)[-2:] == ["--plot", "none"]  # no matplotlib
    assert tuner.progress("run: 62% about 20 s left: Searching for better gains") == \
        tuner.Progress(62, 20, "Searching for better gains")
    assert tuner.progress("run: 3%: Learning your heater from the capture") == \
        tuner.Progress(3, None, "Learning your heater from the capture")
    assert tuner.progress("progress: fitting 3/7") is None  # a step's own line: not the run's, not a message
    assert tuner.progress("twin-tune: run: 3% was a message") is None
    edited = tuner.check_command(tmp_path, "extruder", Gains(20.0, 1.5, 60.0))
    assert edited[1:] == ["--from-log", str(tmp_path / "capture.txt"), "--heater", "extruder", "--current-gains",
                          "20,1.5,60", "--method", "marlin", "--cross-check", "0", "--json",
                          str(tmp_path / "check.json"), "--progress", "lines", "--plot", "none"]


def test_start_reads_the_gains_then_captures_the_autotune(session, printer):
    assert session.start("extruder", 210.0, 8, TIMEOUT_S) is None
    assert printer.sent == ["M503", "M303 E0 S210 C8"]
    session.on_sending("M503")
    reply(session, *M503)
    session.on_sending("M303 E0 S210 C8")
    assert session.phase == tab.AUTOTUNE and session.current == Gains(19.96, 2.06, 48.23)
    reply(session, "PID Autotune start", " T:24.97 /0.00 B:24.97 /0.00 @:127 B@:0")
    assert session.capture == ["Send: M303 E0 S210 C8", "Recv: PID Autotune start",
                               "Recv:  T:24.97 /0.00 B:24.97 /0.00 @:127 B@:0"]
    assert any(m.get("line") == "Recv: PID Autotune start" and m["sample"] is None for m in session.published)


@pytest.mark.parametrize("why", ["The printer is busy (Printing): it must be idle, not printing",
                                 "The printer is not connected (Offline): connect it first"])
def test_start_refuses_a_printer_that_cannot_take_it_and_sends_nothing(session, printer, why):
    printer.refused = why
    assert session.start("extruder", 210.0, 8, TIMEOUT_S) == why
    assert printer.sent == [] and session.phase == tab.IDLE


def test_start_refuses_while_a_run_is_on(session, printer):
    session.start("extruder", 210.0, 8, TIMEOUT_S)
    assert session.start("extruder", 210.0, 8, TIMEOUT_S) == "Busy: reading the printer's gains"
    assert session.paste("PID Autotune start", "extruder") == "Busy: reading the printer's gains"
    assert printer.sent == ["M503", "M303 E0 S210 C8"]


@pytest.mark.parametrize(("args", "error"), [
    (("nozzle", 210.0, 8), "heater 'nozzle': choose one of extruder, heater_bed"),
    (("extruder", 0.0, 8), "target 0 C: must be above 0 C"),
    (("extruder", 210.0, 2), "cycles 2: Marlin's autotune needs at least 3"),
    (("extruder", 210.0, 21), "cycles 21: Marlin's M303 runs at most 20 (it clamps C to 3..20)"),
])
def test_bad_requests_are_one_line(session, printer, args, error):
    assert session.start(*args, TIMEOUT_S) == error
    assert printer.sent == []


def test_the_cycles_go_up_to_the_top_of_m303s_range(session, printer):
    assert session.start("heater_bed", 60.0, 20, TIMEOUT_S) is None
    assert printer.sent == ["M503", "M303 E-1 S60 C20"]


def _autotune(session: tab.Session) -> None:
    session.start("extruder", 210.0, 8, TIMEOUT_S)
    session.on_sending("M503")
    reply(session, *M503)
    session.on_sending("M303 E0 S210 C8")


@pytest.mark.parametrize("failure", ["PID Autotune failed! Temperature too high", "PID Autotune failed! timeout",
                                     "PID Autotune failed! Bad heater id"])
def test_a_failed_autotune_says_the_firmwares_own_words(session, failure):
    _autotune(session)
    reply(session, "PID Autotune start", failure, "ok")
    assert (session.phase, session.error) == (tab.IDLE, failure)
    assert session.published[-1]["state"]["error"] == failure


def test_an_autotune_without_marlins_result_says_so(session):
    _autotune(session)
    reply(session, "echo:Unknown command: \"M303 E0 S210 C8\"", "ok")
    assert session.error == "M303 E0 S210 C8 ended without Marlin's result (no 'PID Autotune finished' line)"


def test_a_kill_during_the_autotune_is_the_firmwares_error_line(session):
    _autotune(session)
    reply(session, "Error:Thermal Runaway, system stopped! Heater_ID: 0", "Error:Printer halted. kill() called!")
    session.on_printer_lost("Error:Printer halted. kill() called!")
    assert session.error == "Error:Thermal Runaway, system stopped! Heater_ID: 0"


def test_a_silent_printer_times_out(session):
    session.start("extruder", 210.0, 8, 0.05)
    session.on_sending("M503")
    assert until(lambda: session.phase == tab.IDLE)
    assert session.error == "The autotune timed out: no result from the printer within 0.000833333 min"


def _answered(session: tab.Session, answer: dict) -> None:
    session.run_id, session.phase, session.answer = "run", tab.ANSWER, answer


def test_apply_sends_the_answer_then_reads_it_back(session, printer):
    _answered(session, ANSWER)
    assert session.apply() is None
    assert printer.sent == ["M301 E0 P22.37 I1.873 D66.81", "M500", "M503"]
    reply(session, "ok", "echo:Settings Stored (144 bytes; crc 41611)", "ok")
    session.on_sending("M503")
    reply(session, "echo:; Hotend PID:", "echo:  M301 P22.37 I1.87 D66.81", "echo:; Bed PID:",
          "echo:  M304 P86.92 I10.40 D484.20", "ok")
    assert session.phase == tab.APPLIED
    assert session.applied == {"holds": True, "read": {"kp": 22.37, "ki": 1.87, "kd": 66.81},
                               "line": "The printer holds the new gains: M301 P22.37 I1.87 D66.81 (M503), stored with M500"}


def test_apply_says_when_the_printer_does_not_hold_the_gains(session):
    _answered(session, ANSWER)
    session.apply()
    reply(session, "echo:M301 gains clamped to the twin's range", "ok", "echo:Error writing to EEPROM!",
          "echo:Settings Stored (144 bytes; crc 41611)", "ok")
    session.on_sending("M503")
    reply(session, "echo:  M301 P19.96 I2.06 D48.23", "ok")
    assert session.applied["holds"] is False
    assert session.applied["line"] == ("The printer reports M301 P19.96 I2.06 D48.23 after Apply, not the gains "
                                       "sent (M301 E0 P22.37 I1.873 D66.81)")


def test_apply_reports_an_eeprom_that_did_not_store(session):
    _answered(session, ANSWER)
    session.apply()
    reply(session, "ok", "echo:Error writing to EEPROM!", "echo:Settings Stored (144 bytes; crc 41611)", "ok")
    session.on_sending("M503")
    reply(session, "echo:  M301 P22.37 I1.87 D66.81", "ok")
    assert session.applied["holds"] is False
    assert session.applied["line"] == ("The printer holds M301 P22.37 I1.87 D66.81, but it answered: "
                                       "echo:Error writing to EEPROM!")


def test_keep_your_gains_has_nothing_to_apply(session, printer):
    _answered(session, {**ANSWER, "verdict": "keep your gains", "answer": None, "commands": []})
    assert session.apply() == "There are no new gains to apply"
    assert printer.sent == []


def test_apply_refuses_a_busy_printer(session, printer):
    _answered(session, ANSWER)
    printer.refused = "The printer is busy (Printing): it must be idle, not printing"
    assert session.apply() == printer.refused
    assert printer.sent == [] and session.phase == tab.ANSWER


def test_an_empty_paste_is_refused(session):
    assert session.paste("\n  \n", "extruder") == "The pasted capture is empty: paste the console text of an M303 run"


@pytest.mark.parametrize("binary", [
    "\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR",  # a file's bytes as latin-1
    "PK\x03\x04\x14\x00\x06\x00",  # a zip's
    "Recv: PID Autotune start\nRecv: \ufffd\ufffd\ufffd",  # bytes that are not UTF-8, as a browser reads them
])
def test_a_capture_that_is_not_text_is_refused_and_not_tuned(session, monkeypatch, binary):
    monkeypatch.setattr(tuner, "run", lambda *args: pytest.fail("a binary capture reached twin-tune"))
    assert session.paste(binary, "extruder") == ("The capture is not text (it holds control bytes, as a binary file "
                                                 "does): paste the console text of an M303 run")
    assert session.phase == tab.IDLE and session.run_id is None


def test_a_capture_with_tabs_and_crlf_is_text():
    assert is_text("Send: M303 E0 S210 C8\r\nRecv:\t T:210.00 /0.00 @:0 \u00b0C\n")


@pytest.mark.slow
def test_without_matplotlib_the_answer_has_no_plot_and_says_why(session, monkeypatch, hardware_logs):
    """The real twin-tune on a real M303 capture, as in an OctoPrint environment without matplotlib
    (.ci/run runs this test in one, matplotlib uninstalled: no plot is asked for, so none is needed)."""
    assert tuner.twin_tune().exists(), f"{tuner.twin_tune()}: the package is not installed in this environment"
    monkeypatch.setattr(tuner, "can_plot", lambda: False)
    capture = (hardware_logs / M303_CAPTURE).read_text()
    assert session.paste(capture, "extruder") is None
    assert until(lambda: session.phase != tab.TUNING, TUNE_TIMEOUT_S), "twin-tune did not end"
    state = session.state()
    assert (state["phase"], state["error"]) == (tab.ANSWER, None)
    assert state["answer"]["plot"] is None and state["plot"] is False and session.plot() is None
    assert state["no_plot"] == tuner.NO_MATPLOTLIB
    # what the tab listed on the way: twin-tune's notes, not its step lines nor its wall time (for a terminal)
    assert not [m for m in state["messages"] if m.startswith(("progress: ", "run: ")) or tuner.TIMING_RE.match(m)]


def test_a_paste_takes_the_gains_to_beat_from_m503_in_it(session, monkeypatch):
    ran = threading.Event()

    def run(run_dir, heater, current, on_progress, on_message):
        assert (run_dir / tuner.CAPTURE).read_text() == "Recv: echo:  M301 P19.96 I2.06 D48.23\nRecv: bias: 1\n"
        ran.current = current  # type: ignore[attr-defined]
        ran.set()
        return tuner.Outcome(None, "twin-tune: capture.txt line 2: a bias line without bias, d, min and max")

    monkeypatch.setattr(tuner, "run", run)
    assert session.paste("Recv: echo:  M301 P19.96 I2.06 D48.23\nRecv: bias: 1", "extruder") is None
    assert ran.wait(10) and ran.current == Gains(19.96, 2.06, 48.23)  # type: ignore[attr-defined]
    assert until(lambda: session.phase == tab.IDLE)
    assert session.error == "twin-tune: capture.txt line 2: a bias line without bias, d, min and max"


def test_the_live_graph_reads_the_heaters_reports_and_the_cycles_their_bias_lines():
    status = " T:207.63 /0.00 B:24.97 /0.00 @:127 B@:0"
    assert reading(status, "extruder") == (207.63, 100.0)
    assert reading(status, "heater_bed") == (24.97, 0.0)
    assert reading(" bias: 82 d: 82 min: 207.03 max: 216.78 T:209.16 /0.00 B:24.97 /0.00 @:82 B@:0",
                   "extruder") == pytest.approx((209.16, 100 * 82 / 127))
    assert reading("echo:  M301 P19.96 I2.06 D48.23", "extruder") is None
    assert reading(" T:210.00 /0.00", "extruder") is None  # no power: not a report of M303's
    assert is_cycle_end(" bias: 79 d: 79 min: 207.03 max: 213.16 Ku: 32.84 Tu: 19.33")
    assert not is_cycle_end("Recv:  Kp: 19.71 Ki: 2.04 Kd: 47.62")


def test_the_autotune_feeds_the_graph_the_cycles_and_one_bar(session):
    _autotune(session)
    assert session.state()["progress"]["words"] == "Your printer's autotune (M303 E0 S210 C8): heating to 210 C, " \
                                                   "the first swing"
    reply(session, "PID Autotune start", " T:25.00 /0.00 B:24.97 /0.00 @:127 B@:0",
          " T:117.50 /0.00 B:24.97 /0.00 @:127 B@:0")
    assert session.state()["progress"]["percent"] == round(100 * tab.AUTOTUNE_SHARE * 0.5 / 9)  # half-way heated
    reply(session, " T:212.94 /0.00 B:24.97 /0.00 @:0 B@:0")
    for cycle in range(3):
        reply(session, f" bias: 8{cycle} d: 8{cycle} min: 207.03 max: 216.78 T:209.16 /0.00 B:24.97 /0.00 @:82 B@:0")
    state = session.state()
    assert state["trace"] == [(25.0, 100.0), (117.5, 100.0), (212.94, 0.0), *[(209.16, 100 * 82 / 127)] * 3]
    assert (state["cycles"], state["cycles_done"], state["target_c"]) == (8, 3, 210.0)
    bar = state["progress"]
    assert bar["words"] == "Your printer's autotune (M303 E0 S210 C8): 3 of 8 cycles done"
    assert bar["percent"] == round(100 * tab.AUTOTUNE_SHARE * (1 + 3) / 9)  # heated, then 3 of the 8 cycles
    assert bar["left_of"] == "the autotune"
    assert bar["left_s"] is not None and bar["left_s"] >= 0  # from the cycles' own pace: 5 more cycles
    line = session.published[-1]
    assert line["line"].startswith("Recv:  bias: 82") and line["cycles_done"] == 3 and line["progress"] == bar


def test_the_twins_run_continues_the_bar_after_the_autotune(session, monkeypatch):
    told = threading.Event()
    done = threading.Event()

    def run(run_dir, heater, current, on_progress, on_message):
        on_progress(tuner.Progress(40, 12, "Searching for better gains"))
        told.set()
        done.wait(10)
        return tuner.Outcome(None, "twin-tune: stopped")

    monkeypatch.setattr(tuner, "run", run)
    _autotune(session)
    reply(session, "PID Autotune finished! Put the last Kp, Ki and Kd constants from below into Configuration.h",
          "ok")
    assert told.wait(10)
    bar = session.state()["progress"]
    done.set()
    assert bar == {"percent": round(100 * tab.AUTOTUNE_SHARE + (1 - tab.AUTOTUNE_SHARE) * 40), "left_s": 12,
                   "left_of": None, "words": "The twin: Searching for better gains"}
    assert until(lambda: session.phase == tab.IDLE) and session.state()["progress"] is None


PROOF = [{"member": "fopdt", "candidate": "answer", "runs": 10, "trips": 0, "overshoot_c": [1.2, 1.38],
          "hold_error_c": [0.33, 0.34], "chatter": [0.014, 0.015]},
         {"member": "fopdt", "candidate": "yours", "runs": 10, "trips": 0, "overshoot_c": [2.8, 2.97],
          "hold_error_c": [0.74, 0.8], "chatter": [0.024, 0.025]}]


def _checked(monkeypatch, session, rows: list[dict]) -> list:
    """Answer, then check edited gains with a twin-tune whose proof of them gives ``rows``."""
    calls = []

    def quick(run_dir, heater, edited, on_progress, on_message):
        calls.append(edited)
        return tuner.Outcome({"verdict": "keep your gains", "proof": rows}, None)

    monkeypatch.setattr(tuner, "check", quick)
    _answered(session, {**ANSWER, "proof": PROOF})
    return calls


def test_edited_gains_are_checked_on_the_twin_then_applied(session, printer, monkeypatch):
    edit = Gains(20.0, 1.5, 60.0)
    rows = [{**PROOF[1], "overshoot_c": [1.5, 1.61], "hold_error_c": [0.4, 0.41]}]
    calls = _checked(monkeypatch, session, rows)
    assert session.apply(edit) == "P20 I1.5 D60: check the edited gains on the twin first (Check these gains)"
    assert session.check(edit) is None
    assert until(lambda: session.phase == tab.ANSWER) and calls == [edit]
    checked = session.state()["checked"]
    assert checked["trips"] is False and checked["gains"] == {"kp": 20.0, "ki": 1.5, "kd": 60.0}
    assert checked["line"] == ("P20 I1.5 D60 never trips on the 1 plant the capture allows (10 runs each): worst "
                               "overshoot 1.61 C (the answer 1.38 C, your printer's 2.97 C), worst hold error 0.41 C "
                               "(0.34 C, 0.80 C)")
    assert session.apply(Gains(20.0, 1.5, 61.0)).startswith("P20 I1.5 D61: check the edited gains")
    assert session.apply(edit) is None
    assert printer.sent == ["M301 E0 P20 I1.5 D60", "M500", "M503"]
    reply(session, "ok", "ok")
    session.on_sending("M503")
    reply(session, "echo:  M301 P20.00 I1.50 D60.00", "ok")
    assert session.applied["holds"] is True


def test_edited_gains_that_trip_on_the_twin_are_not_applied(session, printer, monkeypatch):
    edit = Gains(80.0, 30.0, 1.0)
    _checked(monkeypatch, session, [{**PROOF[1], "trips": 4}])
    session.check(edit)
    assert until(lambda: session.phase == tab.ANSWER)
    line = session.checked["line"]
    assert line == ("P80 I30 D1 trips thermal protection on the twin (fopdt in 4 of 10 runs): not applied (the twin "
                    "applies no gains it saw trip)")
    assert session.apply(edit) == line and printer.sent == []


def test_a_check_refuses_what_is_not_gains_and_says_twin_tunes_error(session, monkeypatch):
    _answered(session, ANSWER)
    assert session.check(Gains(-1.0, 1.0, 1.0)) == "kp -1: must be a number >= 0"
    monkeypatch.setattr(tuner, "check", lambda *args: tuner.Outcome(None, "The twin cannot use this capture: x"))
    assert session.check(Gains(1e9, 1.0, 1.0)) is None
    assert until(lambda: session.phase == tab.ANSWER)
    assert session.error == "The twin cannot use this capture: x" and session.checked is None
    assert check.summary(Gains(1, 1, 1), {"proof": []}, ANSWER)["trips"] is True  # no proof: never applied


def test_the_bed_gains_go_with_m304():
    assert Gains(86.92, 10.4, 484.2).command("heater_bed") == "M304 P86.92 I10.4 D484.2"
    assert Gains(22.37, 1.873, 66.81).command("extruder") == "M301 E0 P22.37 I1.873 D66.81"
