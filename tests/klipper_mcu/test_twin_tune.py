"""TWIN_TUNE and TWIN_APPLY from the console: the registry's klippy on the twin MCU with
tools/klipper_host/twin_tune.cfg included, Moonraker 0.11 on top, and twin-moonraker-agent as its
agent. The macros go in through Moonraker's HTTP API as a front end's console sends them, and the
console is read back from /server/gcode_store. Every wait is on a console line or a state, with a
hang guard of minutes; no wall-clock time is asserted."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import unavailable
from tests.klipper_mcu.test_moonraker import http, start_moonraker
from tools.klipper_host.session import MOONRAKER_VENV_ENV, ROOT, Missing, missed_schedule, venv_command

pytestmark = pytest.mark.slow

MACROS = ROOT / "tools" / "klipper_host" / "twin_tune.cfg"
WAIT_S = 900.0  # hang guard: PID_CALIBRATE at 10 x, or the longest step of a twin-tune, on a loaded 2-core machine
SECTION = "heater_generic hotend"
READY_LINE = "ready for TWIN_TUNE and TWIN_APPLY"
# the agent's twin-tune at a small budget: these tests are of the console's loop, the tune's search has its own
TUNE_ARGS = ("--tune-arg=--budget=90", "--tune-arg=--proof=2")
DOC = ROOT / "docs" / "klipper.md"
TRANSCRIPT_BEGIN, TRANSCRIPT_END = "<!-- twin_tune transcript: begin -->\n```text\n", "```\n<!-- twin_tune transcript: end -->"
TEMPERATURES = "B:... T0:... (PID_CALIBRATE's temperatures, one line a second)"
# a line of twin-tune's progress: how many a run prints turns on its plants, so the doc's are not compared
PROGRESS_LINE = re.compile(r"^// TWIN_TUNE: [^:]+ \d+/\d+$")
NUMBER = re.compile(r"\d+(\.\d+)?")
UNCHANGED = re.compile(r"unchanged \(N( C)?\)")
# the why line's clause for an answer whose hold is worse (tools/tuning/verdict.py gain_line): whether the answer
# holds worse than yours is a number of the run too; what the clause says is tested in tests/tools/tuning
WORSE_HOLD = re.compile(r"[,;] the worse hold buys .*\)$")


class Printer:
    """klippy on the twin MCU, Moonraker and the agent; the console as the front ends see it."""

    def __init__(self, session, base: str, spawn, section: str = SECTION):
        self.session, self.base, self.spawn, self.workdir = session, base, spawn, session.workdir
        self.section = section  # the tuned heater's printer.cfg section
        self.state_dir = self.workdir / "agent-state"
        self.agent: subprocess.Popen | None = None
        self.agents = 0

    def start_agent(self) -> None:
        """Start twin-moonraker-agent and wait for its ready line (its methods are registered with klippy then)."""
        first = len(self.console())
        self.agents += 1
        with open(self.workdir / f"agent{self.agents}.err", "w") as err:
            self.agent = self.spawn([sys.executable, "-m", "tools.klipper_host.agent", "--moonraker", self.base,
                                     "--state-dir", str(self.state_dir), *TUNE_ARGS], stderr=err, cwd=ROOT)
        self.wait_line(READY_LINE, first)

    def send(self, script: str) -> int:
        """Type ``script`` in the console; the index of the console's next line."""
        first = len(self.console())
        assert http(self.base + "/printer/gcode/script", {"script": script}) == "ok"
        return first

    def console(self) -> list[str]:
        """The console's lines (a response of several lines is one entry of the store)."""
        store = http(self.base + "/server/gcode_store?count=1000")["gcode_store"]
        return [line for entry in store for line in entry["message"].split("\n")]

    def wait_line(self, text: str, first: int) -> list[str]:
        """The console from line ``first`` on, once a line there contains ``text``. A hang guard of WAIT_S
        without a sign of progress: a new console line (the agent prints each of twin-tune's steps) or CPU time
        spent by the agent's twin-tune; on a busy machine a tune at nice 10 takes what it takes. Not the agent's
        own CPU time: it spends some on every notification Moonraker sends, so a stuck job would never time out."""
        deadline, seen, polls = time.monotonic() + WAIT_S, (0, 0), 0
        while True:
            lines = self.console()[first:]
            if any(text in line for line in lines if not line.startswith("RESPOND ")):  # not the agent's command
                return lines
            assert self.agent is None or self.agent.poll() is None, self.agent_err()
            progress = (len(lines), 0 if self.agent is None else cpu_ticks(self.agent.pid, own=False))
            if progress != seen:
                deadline, seen = time.monotonic() + WAIT_S, progress
            assert time.monotonic() < deadline, f"no console line with {text!r}, none new for {WAIT_S:g} s: {lines[-20:]}"
            polls += 1
            if polls % 25 == 0:  # klippy lost the MCU (a busy machine): fail now, the runner starts it again slower
                lost = missed_schedule(self.workdir)
                assert lost is None or not lost.startswith("klippy:"), f"{lost} while waiting for {text!r}"
            time.sleep(0.2)

    def agent_err(self) -> str:
        return (self.workdir / f"agent{self.agents}.err").read_text()

    def gains(self) -> dict:
        query = self.base + "/printer/objects/query?configfile=settings"
        settings = http(query)["status"]["configfile"]["settings"][self.section]
        return {k: settings[k] for k in ("control", "pid_kp", "pid_ki", "pid_kd")}


def moonraker_command() -> Path:
    """Moonraker's console script; unavailable (a failure under CI=true) without it or the agent's client."""
    try:
        command = venv_command(MOONRAKER_VENV_ENV)
        import websocket  # noqa: F401  the agent's client: the 'moonraker' extra
    except Missing as exc:
        unavailable(str(exc))
    except ImportError:
        unavailable("no websocket-client for twin-moonraker-agent: pip install -e '.[moonraker]'")
    return command


@pytest.fixture
def printer(klipper) -> Printer:
    command = moonraker_command()
    return klipper.fixture("the printer fixture", lambda: start_printer(klipper, command))


def start_printer(klipper, moonraker_command: Path, *mcu_args: str, section: str = SECTION,
                  **session_options) -> Printer:
    """A session (twin-klipper-mcu given ``mcu_args``; KlipperSession's ``session_options``) with the macros,
    Moonraker on it and the agent (their processes the session's runner's); ``section`` is the heater whose
    gains ``Printer.gains`` reads."""
    session = klipper(*mcu_args, extra_config=f"[include {MACROS}]\n", **session_options)
    base = start_moonraker(moonraker_command, session, klipper.spawn, WAIT_S)
    printer = Printer(session, base, klipper.spawn, section)
    printer.start_agent()
    return printer


def transcript(console: list[str]) -> list[str]:
    """The console as the user sees it: the responses and the TWIN_ commands typed; the agent's own
    commands (RESPOND, PID_CALIBRATE, RESTART) left out, PID_CALIBRATE's temperature lines as one line,
    and the idle timeout's M84, which the twin's printer without steppers does not know."""
    out: list[str] = []
    for line in console:
        if line.startswith("B:"):
            line = TEMPERATURES
        elif not line.startswith(("//", "!!", "TWIN_")) or line == '// Unknown command:"M84"':
            continue
        if not out or out[-1] != line:
            out.append(line)
    return out


def comparable(lines: list[str]) -> list[str]:
    """Lines to compare with the doc's: numbers masked (gains, temperatures and dates differ run to run within
    the band test_klippy.py holds them to), progress lines out. A term that changes by less than its last digit
    reads "unchanged (N C)" rather than "N -> N C", and an answer that holds worse says what that buys: which
    one a run prints is a number too."""
    masked = (NUMBER.sub("N", line) for line in lines if not PROGRESS_LINE.match(line))
    return [WORSE_HOLD.sub("", UNCHANGED.sub(r"N -> N\1", line)) for line in masked]


def doc_transcript() -> list[str]:
    text = DOC.read_text()
    start = text.index(TRANSCRIPT_BEGIN) + len(TRANSCRIPT_BEGIN)
    return text[start:text.index(TRANSCRIPT_END)].splitlines()


def answer_gains(lines: list[str]) -> dict[str, str]:
    """The gains of the console's answer line as printed: {'pid_Kp': '8.629', 'pid_Ki': ..., 'pid_Kd': ...}."""
    answer_line = next(line for line in lines if "TWIN_TUNE: answer:" in line)
    return dict(part.split("=") for part in answer_line.split(": ")[2].split()[:3])


def errors(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("!!")]


def apply_holds(printer: Printer, answer: dict[str, str]) -> None:
    """TWIN_APPLY: no error, and after the restart the printer's configfile holds the answer's gains."""
    first = printer.send("TWIN_APPLY")
    lines = printer.wait_line("TWIN_APPLY: after the restart", first)
    assert errors(lines) == [], lines
    held = printer.gains()
    assert held["control"] == "pid"
    for key in ("pid_Kp", "pid_Ki", "pid_Kd"):
        assert held[key.lower()] == pytest.approx(float(answer[key]), abs=5e-4)


def test_twin_tune_then_twin_apply_holds_the_gains(printer):
    original = printer.session.config_path.read_text()
    before = printer.gains()
    first = printer.send("TWIN_TUNE HEATER=hotend TARGET=210")
    lines = printer.wait_line("TWIN_TUNE: answer:", first)
    assert errors(lines) == []
    assert any(line.startswith("// PID parameters: pid_Kp=") for line in lines)  # PID_CALIBRATE's own reply
    assert any("T0:" in line for line in lines)  # its temperatures: the progress
    assert "// TWIN_TUNE: verdict: new gains" in lines
    assert printer.gains() == before  # nothing applied yet
    assert printer.session.config_path.read_text() == original
    answer = answer_gains(lines)

    apply_holds(printer, answer)
    config = printer.session.config_path.read_text()
    assert "#*# [heater_generic hotend]" in config and f"#*# pid_kp = {answer['pid_Kp']}" in config
    assert "\n#pid_Kp: 22.2\n" in config  # the regular part's gains commented out, as SAVE_CONFIG does
    backups = list(printer.session.config_path.parent.glob("printer-*.cfg"))
    assert [b.read_text() for b in backups] == [original]
    lines = transcript(printer.console())
    (printer.workdir / "transcript.txt").write_text("\n".join(lines) + "\n")
    assert comparable(lines) == comparable(doc_transcript()), f"docs/klipper.md's transcript; this run's is {lines}"


@pytest.mark.parametrize("script, message", [
    ("TWIN_TUNE HEATER=nozzle TARGET=210", "!! TWIN_TUNE: HEATER=nozzle: no such heater (this printer has: hotend, "
                                           "heater_bed)"),
    ("TWIN_TUNE HEATER=hotend TARGET=400", "!! TWIN_TUNE: TARGET=400: beyond hotend's limits (min_temp 0, "
                                           "max_temp 300)"),
    ("TWIN_TUNE HEATER=hotend", "!! TWIN_TUNE: TARGET is missing: a temperature in C below hotend's max_temp 300"),
    ("TWIN_TUNE HEATER=heater_bed TARGET=60", "!! TWIN_TUNE: HEATER=heater_bed: control is watermark, not pid: "
                                              "the twin tunes PID gains"),
    ("TWIN_APPLY", "!! TWIN_APPLY: no answer to apply: run TWIN_TUNE first"),
])
def test_bad_input_is_one_console_line_and_nothing_changes(printer, script, message):
    original, before = printer.session.config_path.read_text(), printer.gains()
    first = printer.send(script)
    lines = printer.wait_line("!!", first)
    time.sleep(1.0)  # a second line, if the agent printed one, would be in the store by now
    assert [line for line in printer.console()[first:] if line.startswith(("!!", "// TWIN"))] == [message]
    assert printer.session.config_path.read_text() == original and printer.gains() == before, lines


def test_a_log_without_a_heat_up_is_one_line(printer):
    """FROM_LOG=1 on a klippy.log that only idled: twin-tune cannot fit it, which is said in one line."""
    original = printer.session.config_path.read_text()
    first = printer.send("TWIN_TUNE HEATER=hotend TARGET=210 FROM_LOG=1")
    lines = printer.wait_line("!!", first)
    assert len(errors(lines)) == 1 and errors(lines)[0].startswith("!! TWIN_TUNE: stopped: twin-tune exited 2: ")
    assert printer.session.config_path.read_text() == original


def cpu_ticks(pid: int, own: bool = True) -> int:
    """CPU clock ticks (user and system) a process (unless not ``own``) and its living descendants have spent;
    0 once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        mine = int(fields[11]) + int(fields[12]) if own else 0
        return mine + sum(cpu_ticks(child) for child in children(pid))
    except (OSError, IndexError, ValueError):
        return 0


def children(pid: int) -> list[int]:
    """The process's children, whichever of its threads started them."""
    return [int(c) for task in Path(f"/proc/{pid}/task").iterdir() for c in (task / "children").read_text().split()]


def test_the_agent_dying_mid_tune_is_said_when_it_is_back(printer):
    original, before = printer.session.config_path.read_text(), printer.gains()
    first = printer.send("TWIN_TUNE HEATER=hotend TARGET=210")
    printer.wait_line("TWIN_TUNE: the twin tunes hotend", first)
    assert printer.agent is not None
    tuners = children(printer.agent.pid)
    assert tuners  # twin-tune, the agent's child
    printer.agent.send_signal(signal.SIGKILL)
    printer.agent.wait()
    deadline = time.monotonic() + WAIT_S
    while any(Path(f"/proc/{pid}").exists() and "Z" not in Path(f"/proc/{pid}/stat").read_text().split()[2]
              for pid in tuners):
        assert time.monotonic() < deadline, "twin-tune outlived the agent"
        time.sleep(0.2)
    first = len(printer.console())
    printer.start_agent()  # as systemd's Restart=always does
    lines = printer.wait_line("!!", first)
    assert errors(lines) == ["!! TWIN_TUNE: the agent stopped during the tune of hotend at 210 C: the tune was lost "
                             "and nothing was applied"]
    assert printer.session.config_path.read_text() == original and printer.gains() == before
    first = printer.send("TWIN_APPLY")
    assert errors(printer.wait_line("!!", first)) == ["!! TWIN_APPLY: no answer to apply: run TWIN_TUNE first"]



def test_klippy_shut_down_mid_tune_is_one_line_once_it_is_back(printer):
    """An emergency stop under PID_CALIBRATE (a front end's button: Moonraker's /printer/emergency_stop, which
    does not wait for the running command): the agent's PID_CALIBRATE fails, and once klippy is ready again
    (FIRMWARE_RESTART) the console gets one line of the agent's after klippy's own; no tune ran, nothing was
    applied."""
    original, before = printer.session.config_path.read_text(), printer.gains()
    first = printer.send("TWIN_TUNE HEATER=hotend TARGET=210")
    printer.wait_line("T0:", first)  # PID_CALIBRATE is heating
    assert http(printer.base + "/printer/emergency_stop", {}) == "ok"
    time.sleep(1.0)  # the shutdown reaches Moonraker's clients; the agent's PID_CALIBRATE fails
    assert http(printer.base + "/printer/firmware_restart", {}) == "ok"
    lines = printer.wait_line("!! TWIN_TUNE: stopped", first)
    assert errors(lines) == ["!! pid_calibrate interrupted",  # klippy's own, as it stops the command
                             "!! TWIN_TUNE: stopped: pid_calibrate interrupted, nothing was applied"]
    assert not any("TWIN_TUNE: the twin tunes" in line for line in lines)
    assert printer.session.config_path.read_text() == original and printer.gains() == before
    first = printer.send("TWIN_APPLY")  # the agent serves on, and has no answer
    assert errors(printer.wait_line("!!", first)) == ["!! TWIN_APPLY: no answer to apply: run TWIN_TUNE first"]


def test_from_log_tunes_on_the_log_as_it_is(printer):
    """FROM_LOG=1 after the printer heated (a SET_HEATER_TEMPERATURE held a while): no PID_CALIBRATE, a verdict."""
    first = printer.send("SET_HEATER_TEMPERATURE HEATER=hotend TARGET=210")
    query = printer.base + "/printer/objects/query?" + SECTION.replace(" ", "%20") + "&toolhead"
    deadline = time.monotonic() + WAIT_S
    start_s = None
    while (status := http(query)["status"])["toolhead"]["estimated_print_time"] < (start_s or float("inf")) + 60:
        if start_s is None and status[SECTION]["temperature"] > 205.0:
            start_s = status["toolhead"]["estimated_print_time"]  # then a minute of holding
        assert time.monotonic() < deadline, f"the hotend never held 210 C: {status}"
        time.sleep(0.2)
    first = printer.send("TWIN_TUNE HEATER=hotend TARGET=210 FROM_LOG=1")
    lines = printer.wait_line("// TWIN_TUNE: proof:", first)
    assert errors(lines) == [] and not any(line.startswith("PID_CALIBRATE") for line in lines)
    assert any(line.startswith("// TWIN_TUNE: verdict: ") for line in lines)
