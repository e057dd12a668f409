"""twin-moonraker-agent: TWIN_TUNE and TWIN_APPLY (tools/klipper_host/twin_tune.cfg) in any front end's console.

A Moonraker agent (Moonraker 0.11's extension API): it identifies as an agent on Moonraker's websocket
and registers the remote methods twin_tune and twin_apply, which the macros call with
``action_call_remote_method``. It talks to the printer through Moonraker only, and prints with RESPOND:

- TWIN_TUNE HEATER=<name> TARGET=<C> [FROM_LOG=1]: checks the heater and target against the printer's
  config, runs PID_CALIBRATE (its temperature lines are the console's progress) unless FROM_LOG=1,
  fetches the klippy.log Moonraker serves, and runs twin-tune on it in the printer's own loop
  (Klipper's, or Kalico's on Kalico) with the printer's gains (configfile settings) as the answer to
  beat; prints the verdict, why and a short proof summary. Nothing is applied.
- TWIN_APPLY: the last answer (kept in the state folder), on Klipper written into printer.cfg's
  SAVE_CONFIG block (autosave.py) and a restart, then read back from configfile.settings; on Kalico
  with SET_HEATER_PID (live).

A fault says one line: bad input names the field; klippy gone mid-tune is said when it is back;
an agent that stopped mid-tune says so when it starts again (the state folder's mark).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import urllib.error
import urllib.request
from pathlib import Path

from tools.entry import OneLineParser, run_cli
from tools.klipper_host.autosave import AutosaveError, pid_options, save_options
from tools.klipper_host.moonraker_ws import MoonrakerError, MoonrakerSocket
from tools.klipper_host.printer import Heater, TuneRequest, find_heater, parse_request, wait_ready
from tools.klipper_host.tune_job import TuneFailed, proof_summary, run_twin_tune
from twin.limits import UserError

AGENT_NAME = "heater-twin"
AGENT_VERSION = "0.1.0"
GCODE_TIMEOUT_S = 7200.0  # a hang guard: PID_CALIBRATE of a slow bed at real time takes tens of minutes
READY_TIMEOUT_S = 600.0  # klippy's restart on a loaded host
HTTP_TIMEOUT_S = 120.0
ANSWER_FILE = "answer.json"
RUNNING_MARK = "tune.running"  # there while a tune runs: found at start, the last agent stopped mid-tune
KEEP = "keep your gains"


class Agent:
    """One connection to Moonraker and the state folder; ``serve()`` answers the macros until it closes."""

    def __init__(self, moonraker_url: str, state_dir: Path, tune_args: tuple[str, ...] = ()):
        self.http_url = moonraker_url.rstrip("/")
        self.state_dir = Path(state_dir)
        self.state_dir.mkdir(parents=True, exist_ok=True)
        self.tune_args = tune_args
        self.ws = MoonrakerSocket(self.http_url.replace("http", "ws", 1) + "/websocket")
        self._busy = threading.Lock()

    def __repr__(self) -> str:
        return f"Agent({self.http_url}, {self.state_dir})"

    def register(self) -> None:
        self.ws.call("server.connection.identify", {"client_name": AGENT_NAME, "version": AGENT_VERSION,
                                                    "type": "agent", "url": "https://github.com/heater-twin"})
        for method in ("twin_tune", "twin_apply"):
            self.ws.call("connection.register_remote_method", {"method_name": method})

    def serve(self) -> None:
        """Answer the macros' calls until Moonraker's socket closes; each job in a thread, one at a time."""
        self.register()
        print(f"{AGENT_NAME} agent: registered twin_tune and twin_apply at {self.http_url}", file=sys.stderr,
              flush=True)
        self.respond_when_ready(f"{AGENT_NAME} agent {AGENT_VERSION}: ready for TWIN_TUNE and TWIN_APPLY")
        mark = self.state_dir / RUNNING_MARK
        if mark.exists():
            self.respond_when_ready(f"TWIN_TUNE: the agent stopped during {mark.read_text().strip()}: "
                                    "the tune was lost and nothing was applied", error=True)
            mark.unlink()
        while True:
            method, params = self.ws.methods.get()
            if method is None:
                return
            job = {"twin_tune": self.tune, "twin_apply": self.apply}.get(method)
            if job is not None:
                threading.Thread(target=self._run, args=(method.upper(), job, params), daemon=True).start()

    def _run(self, name: str, job, params: dict) -> None:
        if not self._busy.acquire(blocking=False):
            self.respond(f"{name}: a TWIN_TUNE or TWIN_APPLY is still running: try again when it has finished",
                         error=True)
            return
        try:
            job(params)
        except UserError as exc:
            self.respond(f"{name}: {exc}", error=True)
        except (MoonrakerError, TuneFailed, AutosaveError, OSError) as exc:
            self.respond_when_ready(f"{name}: stopped: {exc}; nothing was applied", error=True)
        except Exception as exc:  # the agent's own fault: said as one line, the agent keeps serving
            self.respond_when_ready(f"{name}: internal error ({type(exc).__name__}: {exc}); nothing was applied",
                                    error=True)
        finally:
            self._busy.release()

    def gcode(self, script: str, timeout_s: float = 60.0) -> None:
        self.ws.call("printer.gcode.script", {"script": script}, timeout_s)

    def respond(self, text: str, error: bool = False) -> None:
        """One console line (RESPOND: '// text', or '!! text' for an error); also on the agent's stderr."""
        print(text, file=sys.stderr, flush=True)
        clean = text.replace('"', "'").replace(";", ",").replace("\n", " ")
        try:
            self.gcode(f'RESPOND TYPE={"error" if error else "command"} MSG="{clean}"')
        except MoonrakerError as exc:
            print(f"could not print it on the console: {exc}", file=sys.stderr, flush=True)

    def respond_when_ready(self, text: str, error: bool = False) -> None:
        """``respond`` once klippy is ready (it may be restarting after a fault)."""
        try:
            wait_ready(self.ws, READY_TIMEOUT_S)
        except MoonrakerError as exc:
            print(f"{text} (klippy not ready: {exc})", file=sys.stderr, flush=True)
            return
        self.respond(text, error)

    def tune(self, params: dict) -> None:
        heater = find_heater(self.ws, str(params.get("heater", "")))
        request = parse_request(heater, params)
        (self.state_dir / RUNNING_MARK).write_text(f"the tune of {heater.name} at {request.target_c:g} C")
        try:
            self._tune(heater, request)
        finally:
            (self.state_dir / RUNNING_MARK).unlink(missing_ok=True)

    def _tune(self, heater: Heater, request: TuneRequest) -> None:
        loop = "kalico" if self.ws.call("printer.info").get("app") == "Kalico" else "klipper"
        if not request.from_log:
            self.respond(f"TWIN_TUNE: PID_CALIBRATE HEATER={heater.name} TARGET={request.target_c:g} "
                         "(the temperatures follow)")
            self.gcode(f"PID_CALIBRATE HEATER={heater.name} TARGET={request.target_c:g}", GCODE_TIMEOUT_S)
        log = self.state_dir / "klippy.log"
        log.write_bytes(self.fetch("/server/files/klippy.log"))
        self.respond(f"TWIN_TUNE: the twin tunes {heater.name} at {request.target_c:g} C from klippy.log on "
                     f"{loop.title()}'s loop, against your gains {heater.gains_text()}")
        answer = run_twin_tune(log, heater, request.target_c, loop, self.state_dir, self.tune_args,
                               progress=self.respond)
        answer.update(heater=heater.name, section=heater.section, loop=loop)
        (self.state_dir / ANSWER_FILE).write_text(json.dumps(answer, indent=1) + "\n")
        self.respond(f"TWIN_TUNE: verdict: {answer['verdict']}")
        self.respond(f"TWIN_TUNE: why: {answer['why']}")
        self.respond(f"TWIN_TUNE: proof: {proof_summary(answer)}")
        if answer["verdict"] != KEEP and answer.get("answer"):
            gains = answer["answer"]
            self.respond(f"TWIN_TUNE: answer: pid_Kp={gains['kp']:.3f} pid_Ki={gains['ki']:.3f} "
                         f"pid_Kd={gains['kd']:.3f}: TWIN_APPLY applies it")

    def fetch(self, path: str) -> bytes:
        try:
            with urllib.request.urlopen(self.http_url + path, timeout=HTTP_TIMEOUT_S) as reply:
                return reply.read()
        except (OSError, urllib.error.URLError) as exc:
            raise TuneFailed(f"cannot read {path} from Moonraker: {exc}") from None

    def apply(self, params: dict) -> None:
        path = self.state_dir / ANSWER_FILE
        if not path.exists():
            raise UserError("no answer to apply: run TWIN_TUNE first")
        answer = json.loads(path.read_text())
        if not answer.get("answer") or answer["verdict"] == KEEP:
            raise UserError(f"the last answer ({answer['heater']} at {answer['target_c']:g} C) is "
                            f"'{answer['verdict']}': nothing to apply")
        gains = answer["answer"]
        if answer["loop"] == "kalico":
            self.gcode(f"SET_HEATER_PID HEATER={answer['heater']} KP={gains['kp']:.3f} KI={gains['ki']:.3f} "
                       f"KD={gains['kd']:.3f}")
            self.respond(f"TWIN_APPLY: {answer['heater']} runs pid_Kp={gains['kp']:.3f} pid_Ki={gains['ki']:.3f} "
                         f"pid_Kd={gains['kd']:.3f} now (Kalico's SET_HEATER_PID: until the next restart)")
            return
        self._apply_klipper(answer["section"], pid_options(gains["kp"], gains["ki"], gains["kd"]))

    def _apply_klipper(self, section: str, options: dict[str, str]) -> None:
        config = Path(self.ws.call("printer.info")["config_file"])
        backup = save_options(config, section, options)
        self.respond(f"TWIN_APPLY: [{section}] pid_Kp={options['pid_kp']} pid_Ki={options['pid_ki']} "
                     f"pid_Kd={options['pid_kd']} written to {config.name}'s SAVE_CONFIG block "
                     f"(old file: {backup.name}), restarting")
        seen = self.ws.klippy_ready_count
        self.ws.call("printer.restart")
        wait_ready(self.ws, READY_TIMEOUT_S, seen)
        settings = self.ws.call("printer.objects.query", {"objects": {"configfile": ["settings"]}})
        held = settings["status"]["configfile"]["settings"].get(section.lower(), {})
        got = {k: held.get(k) for k in options if k != "control"}
        if held.get("control") == "pid" and all(abs(float(v) - float(options[k])) < 5e-4
                                                for k, v in got.items() if v is not None):
            self.respond(f"TWIN_APPLY: after the restart the printer holds the gains: pid_Kp={got['pid_kp']:g} "
                         f"pid_Ki={got['pid_ki']:g} pid_Kd={got['pid_kd']:g}")
        else:
            self.respond(f"TWIN_APPLY: after the restart the printer does not hold the gains: [{section}] reads "
                         f"{got}", error=True)


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="twin-moonraker-agent", description="The Moonraker agent behind TWIN_TUNE and "
                           "TWIN_APPLY (tools/klipper_host/twin_tune.cfg; docs/klipper.md).")
    parser.add_argument("--moonraker", default="http://127.0.0.1:7125",
                        help="Moonraker's address (default: %(default)s)")
    parser.add_argument("--state-dir", type=Path, default=Path.home() / "printer_data" / "heater-twin",
                        help="the last answer, the fetched klippy.log and twin-tune's report (default: %(default)s)")
    parser.add_argument("--tune-arg", action="append", default=[], metavar="ARG",
                        help="an argument passed on to twin-tune, e.g. --tune-arg=--budget=200 (repeatable)")
    return parser


def main(argv: list[str] | None = None) -> int:
    def run(args: argparse.Namespace) -> int:
        agent = Agent(args.moonraker, args.state_dir, tuple(args.tune_arg))
        try:
            agent.serve()
        finally:
            agent.ws.close()
        print(f"{AGENT_NAME} agent: Moonraker closed the connection", file=sys.stderr)
        return 1

    return run_cli(build_parser(), run, argv, errors=(MoonrakerError, UserError))


if __name__ == "__main__":
    sys.exit(main())
