"""Bad values at every edge: each CLI's flags and files, twin:// parameters and the public API's arguments.

Every bad value gets one line naming its flag or field and exit status 2 (a CLI), a SerialException
naming the parameter (twin://) or a ValueError naming the argument (the API): no traceback, no internal
message, no run that ends 0 with absurd numbers. The CLIs run in-process (``main(argv)``), a few in a
subprocess as a user types them.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import serial

import protocol  # noqa: F401  (registers twin://)
from tools import bench
from tools.cli import benchfuncs, compare, firmware_report, fit, hold_check, sim, tune
from tools.cli import serial as serial_cli
from tools.docs import crossval, kalico_table, mpc_report, optimtable
from tools.seeds import __main__ as seeds
from twin import BatchTwin, KlipperTwin, PidGains, Twin, make_plant
from twin.build import build_twin
from twin.klipper_batch import KlipperBatch, gains_setups
from twin.klipper_twin import extruder_setup
from twin.scenario import PRESETS
from twin.sensor import SensorChain

ROOT = Path(__file__).resolve().parents[1]
CLIS = {"twin-sim": sim.main, "twin-serial": serial_cli.main, "twin-fit": fit.main, "twin-compare": compare.main,
        "twin-tune": tune.main, "twin-firmware-report": firmware_report.main, "hold_check": hold_check.main,
        "tools.seeds": seeds.main, "benchfuncs": benchfuncs.main, "tools.docs.crossval": crossval.main,
        "tools.docs.mpc_report": mpc_report.main, "tools.docs.optimtable": optimtable.main,
        "tools.docs.kalico_table": kalico_table.main, "tools.bench": bench.main}
INTERNAL = ("Traceback", "internal error", "codec can't", "object has no attribute", "NoneType",
            "cannot convert float", "invalid literal")
GAINS = ["--gains", "13,0.3,70"]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, str]:
    """A small plain-CSV heat-up log, a FIFO, a binary file, a page without markers, a folder."""
    folder = tmp_path_factory.mktemp("bad_inputs")
    log = folder / "heatup.csv"
    t_s = np.arange(0.0, 300.0, 1.0)
    temp_c = 25.0 + 180.0 * (1.0 - np.exp(-t_s / 80.0))
    log.write_text("t_s,temp_c,duty\n" + "".join(f"{t:g},{c:.2f},1\n" for t, c in zip(t_s, temp_c)))
    fifo = folder / "fifo"
    os.mkfifo(fifo)
    binary = folder / "binary.md"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe" * 10)
    page = folder / "page.md"
    page.write_text("# a page without the table's markers\n")
    return {"log": str(log), "fifo": str(fifo), "binary": str(binary), "page": str(page), "dir": str(folder),
            "out": str(folder / "out"), "missing": str(folder / "missing" / "x.png")}


def _cases() -> list[tuple[str, list[str], str]]:
    """(CLI, argv with {placeholders}, what the one line must name)."""
    out = ["--out", "{out}"]
    cases: list[tuple[str, list[str], str]] = []

    def add(cli: str, flag: str, values: list[str], base: list[str] = (), says: str | None = None) -> None:
        for value in values:
            cases.append((cli, [*base, flag, value], flag if says is None else says))

    # twin-sim: every numeric flag, the plant and MPC settings, the outputs, the scenario file
    add("twin-sim", "--duration", ["nan", "inf", "-inf", "0", "-5", "1e300", "5e6", "abc", ""], out)
    add("twin-sim", "--duration", ["4e6"], out, "--duration 4e+06: a run to")  # the trace would not fit
    add("twin-sim", "--target", ["nan", "-50", "1e9", "401", "2.5", "abc"], out)
    add("twin-sim", "--bed-target", ["-1", "500"], out)
    add("twin-sim", "--ambient", ["nan", "inf", "-300", "1000", "121", "x"], out)
    add("twin-sim", "--initial", ["nan", "-300", "1e4"], out)
    add("twin-sim", "--bed-initial", ["inf", "-273.15"], out)
    add("twin-sim", "--seed", ["-1", "1.5", "x", "99999999999999999999999"], out)
    add("twin-sim", "--noise", ["nan", "-1", "1e9", "inf"], out)
    add("twin-sim", "--record-every", ["nan", "-1", "inf", "1e9"], out)
    add("twin-sim", "--record-every", ["700"], out)  # longer than the scenario's 600 s
    add("twin-sim", "--gains", ["nan,1,1", "1,2", "2000,1,1", "1,-1,1", "inf,0,0", "a,b,c"], out, "gains")
    add("twin-sim", "--bed-gains", ["1,nan,1"], out, "gains")
    add("twin-sim", "--set", ["power_w=nan", "power_w=inf", "power_w=1e308", "nonsense=1", "power_w"], out,
        "power_w")
    add("twin-sim", "--bed-set", ["power_w=-inf"], out, "power_w")
    add("twin-sim", "--mpc-from", ["M306 P40 Cnan", "M306 P-1", "M306 Rinf", "M306 A0", "no line here"],
        ["--firmware", "mpc", *out])
    add("twin-sim", "--mpc-from", ["M306 P40"], out)  # without --firmware mpc
    add("twin-sim", "--csv", ["/proc/x.csv", "{dir}", "{fifo}", "{missing}"], out)
    add("twin-sim", "--klipper-log", ["/proc/x.log"], out)
    add("twin-sim", "--plot", ["/proc/x.png", "{missing}", "x.svg"], out)
    add("twin-sim", "--scenario", ["{fifo}", "{binary}", "nope"], out, "")
    add("twin-sim", "--engine", ["bogus"], out)
    add("twin-sim", "--firmware", ["bogus"], out)
    # python -m tools.cli.hold_check
    add("hold_check", "--duration", ["inf", "nan", "0", "-1", "abc"], GAINS)
    add("hold_check", "--duration", ["4e6"], GAINS, "--duration 4e+06: a run to")
    add("hold_check", "--noise", ["nan", "-1", "1e3", "inf"], GAINS)
    add("hold_check", "--target", ["-50", "nan", "1000", "10", "inf"], GAINS)
    add("hold_check", "--target", ["300"], GAINS, "--target 300: the firmware clamps it to 260 C")
    add("hold_check", "--max-chatter", ["nan", "-0.1", "2", "inf"], GAINS)
    add("hold_check", "--max-hold", ["nan", "-1", "inf"], GAINS)
    add("hold_check", "--seeds", ["0", "-1", "x", "1e9", "5000"], GAINS)
    add("hold_check", "--hold-from", ["nan", "-1", "1000"], GAINS)
    add("hold_check", "--gains", ["nan,1,1", "1,2", "-1,0,0", "1e9,0,0", "x"])
    add("hold_check", "--plant", ["bogus"], GAINS)
    # twin-serial (a bad value stops it before it serves)
    add("twin-serial", "--idle-speed", ["1e308", "nan", "-1", "inf", "x", "1001"])
    add("twin-serial", "--speed", ["1e308", "0", "-1", "nan", "x"])
    add("twin-serial", "--corrupt-rx", ["nan", "2", "-0.1", "inf"])
    add("twin-serial", "--seed", ["-1", "x"])
    add("twin-serial", "--baud", ["0", "-5", "x"])
    add("twin-serial", "--tcp", ["x", ":99999", "host:-1"])
    add("twin-serial", "--scenario", ["{fifo}", "nope"], (), "")
    add("twin-serial", "--log", ["{fifo}", "/proc/x.log", "{dir}"])
    add("twin-serial", "--firmware", ["bogus"])
    add("twin-serial", "--plant", ["bogus"])
    add("twin-serial", "--secret-file", ["{fifo}", "{dir}"], ["--tcp", "127.0.0.1:0"])  # a FIFO would block its open
    # twin-fit on a small plain CSV
    add("twin-fit", "--target", ["nan", "0", "1000"], ["{log}"])
    add("twin-fit", "--ambient", ["nan", "-300", "1000"], ["{log}"])
    add("twin-fit", "--power-w", ["0", "nan", "1e9"], ["{log}"])
    add("twin-fit", "--fit-cycles", ["0", "-1", "x"], ["{log}"])
    add("twin-fit", "--segment", ["99", "-1", "x"], ["{log}"])
    add("twin-fit", "--model", ["bogus"], ["{log}"])
    add("twin-fit", "--heater", ["bogus"], ["{log}"])
    add("twin-fit", "--budget", ["0", "-1", "x", "2000000"], ["{log}"])
    add("twin-fit", "--proof", ["0", "-1", "x", "20000"], ["{log}"])
    cases += [("twin-fit", [log], "") for log in ("{fifo}", "{binary}", "{dir}/none.csv", "{dir}")]
    # twin-compare
    add("twin-compare", "--plot", ["/proc/x.png", "{dir}", "x.unknownext", "{missing}"], ["{log}"])
    add("twin-compare", "--ambient", ["nan", "-300", "1e3"], ["{log}"])
    add("twin-compare", "--fit-cycles", ["0", "-1", "x"], ["{log}"])
    add("twin-compare", "--fit-cycles", ["2"], ["{log}"])  # a plain CSV is no M303 capture
    add("twin-compare", "--heater", ["bogus"], ["{log}"])
    cases += [("twin-compare", [log], "") for log in ("{fifo}", "{binary}", "{dir}/none.csv")]
    # twin-tune
    preset = ["--plant", "hotend_cartridge"]
    add("twin-tune", "--plant", ["bogus"])
    add("twin-tune", "--target", ["nan", "-50", "900", "inf"], preset)
    add("twin-tune", "--noise", ["nan", "-1", "1e9"], preset)
    add("twin-tune", "--spread", ["nan", "1.5", "-0.1"], preset)
    add("twin-tune", "--budget", ["0", "-1", "x", "10000000"], preset)
    add("twin-tune", "--proof", ["-2", "x", "1000000"], preset)
    add("twin-tune", "--seed", ["-1", "x"], preset)
    add("twin-tune", "--plot", ["/proc/x.png", "{dir}", "x.unknownext", "{missing}"], preset)
    add("twin-tune", "--controller", ["os:system", "subprocess:run", ":x", "nomodule_xyz:X", "bangbang",
                                      "builtins:print", "..:x", ".x:y", "a b:c", "os.:x"], preset)
    add("twin-tune", "--current-gains", ["1e308,1,1", "1,1e300,1", "1,1,9e9", "nan,1,1", "-1,1,1", "x"], preset)
    add("twin-tune", "--cross-check", ["-1", "nan", "inf"], preset)
    add("twin-tune", "--method", ["guess"], preset)
    add("twin-tune", "--objective", ["fastest"], preset)
    add("twin-tune", "--statistic", ["x"], preset)
    add("twin-tune", "--model", ["x"], preset)
    add("twin-tune", "--from-log", ["{fifo}", "{binary}"], (), "")
    # twin-firmware-report
    add("twin-firmware-report", "--seed", ["-1", "x"])
    add("twin-firmware-report", "--sequences", ["0", "-1", "x", "1000000000"])
    add("twin-firmware-report", "--steps", ["0", "x", "1e9"])
    add("twin-firmware-report", "--doc", ["{binary}", "{fifo}", "{page}", "{dir}", "{dir}/none.md"])
    # python -m tools.seeds
    add("tools.seeds", "--budget", ["x", "-1", "2"], ["000"])
    add("tools.seeds", "--seeds", ["999", "x"])
    add("tools.seeds", "--out", ["/proc/x.md", "{dir}", "{binary}", "{fifo}"])
    cases.append(("tools.seeds", ["bogus"], "seed"))
    cases += [("tools.seeds", ["--check", "--out", page], "--out") for page in ("{binary}", "{fifo}")]
    # python -m tools.bench: its sizes, checked before any work
    add("tools.bench", "--lanes", ["1000000000", "0", "-1"], ["twin"])
    add("tools.bench", "--lines", ["-1", "0"], ["protocol"])
    add("tools.bench", "--requests", ["0"], ["protocol"])
    add("tools.bench", "--captures", ["/abs/*"], ["twin-tune"])
    add("tools.bench", "--duration", ["nan", "-1", "1e300"], ["twin"])
    # the docs' generators and the optimiser benchmark: their pages and outputs, checked before the runs
    add("benchfuncs", "--out", ["/proc/x.md", "{dir}", "{fifo}"], ["--quick"])
    add("benchfuncs", "--doc", ["{binary}", "{fifo}", "{page}", "{dir}/none.md"], ["--quick"])
    add("benchfuncs", "--seed", ["-1"], ["--quick"])
    for generator in ("tools.docs.crossval", "tools.docs.mpc_report", "tools.docs.optimtable", "tools.docs.kalico_table"):
        add(generator, "--doc", ["{binary}", "{fifo}", "{page}"])
    add("tools.docs.kalico_table", "--budget", ["0", "x"])
    add("tools.docs.kalico_table", "--mpc-budget", ["-1", "1e9"])
    return cases


CASES = _cases()


def _call(cli: str, argv: list[str]) -> int:
    """``main(argv)``'s exit status, whether it returns it or argparse raises it."""
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}  # twin-serial installs its own
    try:
        return CLIS[cli](argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)


@pytest.mark.parametrize(("cli", "argv", "names"), CASES, ids=[f"{c}:{' '.join(a)}" for c, a, _ in CASES])
def test_a_bad_cli_value_is_one_line_naming_it_and_exit_2(capfd, files, cli, argv, names):
    argv = [arg.format(**files) for arg in argv]
    names = names.format(**files)
    status = _call(cli, argv)
    captured = capfd.readouterr()  # the file descriptors: a shell command run by mistake writes there
    err = captured.err.strip()
    assert status == 2, (status, err, captured.out[-300:])
    assert err.count("\n") == 0 and err, err
    assert not any(word in err for word in INTERNAL), err
    assert names in err, err
    if names == "":  # a file or a name: the line says which
        assert any(arg in err for arg in argv), err


# -- twin:// --------------------------------------------------------------------------------------
URLS = [
    ("twin://?idle_speed=1e308", "idle speed"), ("twin://?idle_speed=nan", "idle speed"),
    ("twin://?idle_speed=-1", "idle speed"), ("twin://?idle_speed=inf", "idle speed"),
    ("twin://?idle_speed=x", "idle speed"), ("twin://?speed=1e308", "speed"), ("twin://?speed=0", "speed"),
    ("twin://?speed=inf", "speed"), ("twin://?speed=-1", "speed"), ("twin://?speed=fast", "speed"),
    ("twin://?ok_after_resend=maybe", "ok_after_resend"), ("twin://?firmware=x", "firmware"),
    ("twin://?plant=x", "plant preset"), ("twin://?bed_plant=x", "plant preset"),
    ("twin://?scenario={fifo}", "not a regular file"), ("twin://?colour=red", "unknown parameter"),
    ("twin://?speed=1&speed=2", "given twice"), ("twin://host/path", "expected twin://"),
]


@pytest.mark.parametrize(("url", "names"), URLS, ids=[u for u, _ in URLS])
def test_a_bad_twin_url_parameter_is_named(files, url, names):
    with pytest.raises(serial.SerialException) as error:
        serial.serial_for_url(url.format(**files), timeout=0.1)
    message = str(error.value)
    assert names in message and "\n" not in message and not any(word in message for word in INTERNAL)


# -- the public API --------------------------------------------------------------------------------
def _twin() -> Twin:
    return Twin.create("pid", boot_s=0.5)


def _batch() -> BatchTwin:
    return BatchTwin(make_plant("hotend_cartridge"), [PidGains(20, 1, 100)], kernel="numpy")


def _klipper() -> KlipperTwin:
    return KlipperTwin([extruder_setup()])


def _klipper_batch() -> KlipperBatch:
    return KlipperBatch(gains_setups(extruder_setup(make_plant("hotend_cartridge")), [(22.2, 1.08, 114.0)] * 2))


def _set(obj, attribute: str, value) -> None:
    setattr(obj, attribute, value)


def _record_every(value: float, seconds: float) -> None:
    twin = _twin()
    twin.record_every_s = value
    twin.run(seconds)


NAN, INF = math.nan, math.inf
API = [
    *((f"Twin.create(ambient_c={v!r})", lambda v=v: Twin.create(ambient_c=v), "ambient_c")
      for v in (NAN, INF, -300.0, -273.15, 1e9, "x", True)),
    *((f"Twin.create(noise_lsb={v!r})", lambda v=v: Twin.create(noise_lsb=v), "noise_lsb") for v in (NAN, -1.0, 1e6)),
    *((f"Twin.create(seed={v!r})", lambda v=v: Twin.create(seed=v), "seed") for v in (-1, 1.5, "x", 2**64)),
    *((f"Twin.create(boot_s={v!r})", lambda v=v: Twin.create(boot_s=v), "boot_s") for v in (NAN, -1.0, 1e12)),
    *((f"Twin.run({v!r})", lambda v=v: _twin().run(v), "seconds") for v in (NAN, INF, 0.0, -1.0, 1e9, "10")),
    *((f"Twin.run_until({v!r})", lambda v=v: _twin().run_until(v), "t_s") for v in (NAN, INF, 1e12)),
    ("Twin.run(4e6): the trace would not fit", lambda: _twin().run(4e6), "record_every_s"),
    *((f"record_every_s={v!r}", lambda v=v: _record_every(v, 1.0), "record_every_s") for v in (NAN, -1.0, INF)),
    *((f"hotend.target_c={v!r}", lambda v=v: _set(_twin().hotend, "target_c", v), "target_c")
      for v in (NAN, -50, 1e9, INF)),
    ("hotend.gains=NaN", lambda: _set(_twin().hotend, "gains", PidGains(NAN, 1, 1)), "kp"),
    *((f"set_ambient({v!r})", lambda v=v: _twin().set_ambient(v), "ambient_c") for v in (NAN, -300.0)),
    ("flow_mm_s=inf", lambda: _set(_twin(), "flow_mm_s", INF), "flow_mm_s"),
    ("Twin.schedule(nan)", lambda: _twin().schedule(NAN, lambda twin: None), "at_s"),
    *((f"make_plant(ambient_c={v!r})", lambda v=v: make_plant(ambient_c=v), "ambient_c") for v in (NAN, -400.0)),
    ("make_plant(initial_c=inf)", lambda: make_plant(initial_c=INF), "initial_c"),
    ("make_plant(power_w=nan)", lambda: make_plant(power_w=NAN), "power_w"),
    ("SensorChain(noise_lsb=nan)", lambda: SensorChain(noise_lsb=NAN), "noise_lsb"),
    ("build_twin(noise_lsb=inf)", lambda: build_twin(PRESETS["heat_hold"], noise_lsb=INF), "noise_lsb"),
    *((f"BatchTwin.run({v!r})", lambda v=v: _batch().run(v), "seconds") for v in (-1.0, NAN, INF, 0.0, 1e9)),
    *((f"BatchTwin.run_until({v!r})", lambda v=v: _batch().run_until(v), "t_s") for v in (NAN, -5.0)),
    *((f"BatchTwin.set_target({v!r})", lambda v=v: _batch().set_target(v), "target_c") for v in (NAN, -1, 999)),
    ("BatchTwin.schedule(inf)", lambda: _batch().schedule(INF, lambda batch: None), "at_s"),
    *((f"BatchTwin(noise_lsb={v!r})", lambda v=v: BatchTwin(make_plant(), [PidGains(1, 1, 1)], noise_lsb=v),
       "noise_lsb") for v in (NAN, -1.0, [1.0, NAN], "x")),
    *((f"BatchTwin(seed={v!r})", lambda v=v: BatchTwin(make_plant(), [PidGains(1, 1, 1)], seed=v), "seed")
      for v in (-1, 1.5, "x")),
    ("BatchTwin records that would not fit",
     lambda: BatchTwin(make_plant(), [PidGains(1, 1, 1)] * 1000, kernel="numpy").run(4e6), "record=False"),
    *((f"KlipperTwin.set_target({v!r})", lambda v=v: _klipper().set_target("extruder", v), "temp_c")
      for v in (NAN, INF)),
    *((f"KlipperTwin.run_until({v!r})", lambda v=v: _klipper().run_until(v), "t_s") for v in (NAN, INF, -1.0, 1e9)),
    ("KlipperTwin.run_until(4e6): the records would not fit", lambda: _klipper().run_until(4e6), "run shorter"),
    *((f"extruder_setup(pid_{k}=nan)", lambda k=k: extruder_setup(**{f"pid_{k}": NAN}), f"pid_{k}")
      for k in ("kp", "ki", "kd")),
    ("extruder_setup(max_power=nan)", lambda: extruder_setup(max_power=NAN), "max_power"),
    ("HeaterSetup noise_lsb=inf", lambda: KlipperTwin([_noisy_setup(INF)]), "noise_lsb"),
    ("KlipperTwin(seed=-1)", lambda: KlipperTwin([extruder_setup()], seed=-1), "seed"),
    ("set_plant_inputs(fan=2)", lambda: _klipper().set_plant_inputs("extruder", 2.0, 0.0, 25.0), "fan"),
    ("set_plant_inputs(ambient_c=-300)", lambda: _klipper().set_plant_inputs("extruder", 0.0, 0.0, -300.0),
     "ambient_c"),
    ("set_plant_inputs(flow_mm_s=nan)", lambda: _klipper().set_plant_inputs("extruder", 0.0, NAN, 25.0),
     "flow_mm_s"),
    ("pid_calibrate(nan)", lambda: _klipper().pid_calibrate("extruder", NAN), "target_c"),
    ("pid_calibrate(timeout_s=inf)", lambda: _klipper().pid_calibrate("extruder", 200.0, INF), "timeout_s"),
    ("KlipperTwin.schedule(nan)", lambda: _klipper().schedule(NAN, lambda twin: None), "at_s"),
    *((f"KlipperBatch.set_target({v!r})", lambda v=v: _klipper_batch().set_target(v), "temp_c") for v in (NAN, INF)),
    *((f"KlipperBatch.run_until({v!r})", lambda v=v: _klipper_batch().run_until(v), "t_s") for v in (NAN, INF)),
    ("KlipperBatch.schedule(nan)", lambda: _klipper_batch().schedule(NAN, lambda batch: None), "at_s"),
    ("KlipperBatch(seed=-1)", lambda: KlipperBatch([extruder_setup()], seed=-1), "seed"),
]


def _noisy_setup(noise_lsb: float):
    import dataclasses

    return dataclasses.replace(extruder_setup(), noise_lsb=noise_lsb)


@pytest.mark.parametrize(("call", "names"), [(c, n) for _, c, n in API], ids=[label for label, _, _ in API])
def test_a_bad_api_argument_is_a_value_error_naming_it(call, names):
    with pytest.raises(ValueError) as error:
        call()
    message = str(error.value)
    assert names in message and "\n" not in message and not any(word in message for word in INTERNAL), message


def test_at_least_150_bad_values():
    assert len(CASES) + len(URLS) + len(API) >= 150


# -- as a user types them --------------------------------------------------------------------------
TYPED = [
    ["-m", "tools.cli.sim", "--duration", "inf"],
    ["-m", "tools.cli.hold_check", "--gains", "13,0.3,70", "--duration", "inf"],
    ["-m", "tools.cli.serial", "--idle-speed", "1e308"],
    ["-m", "tools.cli.tune", "--plant", "hotend_cartridge", "--controller", "os:system"],
    ["-m", "tools.seeds", "--out", "/proc/x.md"],
]


@pytest.mark.parametrize("argv", TYPED, ids=[" ".join(a[1:3]) for a in TYPED])
def test_a_typed_bad_value_is_one_line_and_exit_2(tmp_path, argv):
    done = subprocess.run([sys.executable, *argv], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 2 and done.stdout == "", (done.returncode, done.stdout, done.stderr)
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert not list(tmp_path.iterdir())  # nothing written, no shell command run
