"""PID against MPC on the same hotend, each tuned by its own firmware autotune on the twin, as a
user would do it; and how close M306 T comes to the model it measures.

``python -m tools.docs.mpc_report --doc docs/firmware.md`` rewrites the generated part of the MPC
section there; without --doc it prints it. Everything runs through the serial layer as twin-serial
serves it (M303, M306 T, M306) and through twin-sim's heat_hold scenario:

1. M306 T on the ``hotend`` preset (Marlin's MPC model with Configuration.h's constants) and on
   the two-node plants twin-fit prints for three captures: the constants found against the
   plant's own;
2. on ``hotend_cartridge`` at 210 C, from ambient: M303 E0 S210 C8 on the pid build gives the
   gains, M306 T then M306 on the mpc build the model; heat_hold (600 s) with each, without and
   with 1 LSB of ADC noise (the autotunes run with the same noise);
3. the same hold with the MPC constants ``twin-tune --controller mpc`` answers on that plant
   (``TUNE_ARGS``: DE from M306 T's result on the preset's ensemble with 1 LSB of ADC noise, proven over
   10 seeds on every plant against M306 T's constants: the answer, or M306 T's where nothing beats
   them), pasted as its M306 line (``twin-sim --firmware mpc --mpc-from``): MPC's constants are its
   model, and a model identified for the closed loop may hold where M306 T's two-node reading of a
   three-node hotend drifts.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_port.marlin.mpc import DEFAULT_CONSTANTS, MpcConstants, MpcController
from firmware_port.marlin.pid import PidGains
from firmware_port.thermistor import B3950_TABLE
from protocol.mpc_commands import mpc_constants_from_text
from protocol.printer import VirtualPrinter
from tools.logs import hardware_logs_dir
from tools.validation.doc_compare import write_section
from tools.cli.args import doc_page
from tools.entry import OneLineParser, run_cli
from twin.build import build_twin
from twin.plants import SPECS, Lumped
from twin.scenario import Scenario, parse_scenario, scenario_for, with_overrides

BEGIN, END = "<!-- mpc-report: begin", "<!-- mpc-report: end -->"
COMMAND = "python -m tools.docs.mpc_report --doc docs/firmware.md"
PLANT = "hotend_cartridge"
TARGET_C = 210
M303_CYCLES = 8
HOLD_FROM_S = 300.0  # heat_hold runs 600 s: the second half is the hold
HOLD_BAND_C = 1.0  # an MPC tune "holds within 1 C"
NOISES_LSB = (0.0, 1.0)
CAPTURES = ("klippy_stats_pdegrazia_kingroon_kp3s_a.csv", "klipper_heattest_onionheater_heattest_200.csv",
            "klippy_stats_icodextrin_ender5_creality427.csv")
CONSTANTS = (("C", "block_heat_capacity_j_k"), ("R", "sensor_responsiveness_per_s"), ("A", "ambient_xfer_w_k"),
             ("F", "fan_ambient_xfer_w_k"))
SERIAL = parse_scenario('name = "serial"\nduration_s = 86400\n', "serial")
DEFINE = re.compile(r"^#define DEFAULT_K([pid]) (\S+)$", re.M)
TUNE_ARGS = ("--controller", "mpc", "--plant", PLANT, "--target", str(TARGET_C), "--seed", "0")


def session(scenario: Scenario, firmware: str, lines: Sequence[str], noise_lsb: float = 0.0) -> str:
    """What a host reads back from the lines, on twin-serial's printer for the scenario's plants."""
    printer = VirtualPrinter(lambda: build_twin(scenario, firmware, with_bed=False, noise_lsb=noise_lsb))
    printer.take_output()
    for line in lines:
        printer.receive(line.encode() + b"\n")
        printer.run_until_idle()
    return printer.take_output().decode()


def plant_scenario(plant: dict[str, float | str]) -> Scenario:
    return with_overrides(SERIAL, plant={"hotend": plant})


def m306_t(scenario: Scenario, noise_lsb: float = 0.0) -> MpcConstants:
    """M306 T, then M306: the model the firmware runs with afterwards."""
    replies = session(scenario, "mpc", ("M306 T", "M306"), noise_lsb)
    if "MPC Autotune finished!" not in replies:
        raise ValueError("M306 T did not finish: " + " | ".join(replies.splitlines()[-3:]))
    return mpc_constants_from_text(replies)


def m303(scenario: Scenario, noise_lsb: float = 0.0) -> PidGains:
    """M303 E0 S210 C8: the gains of its #define lines."""
    replies = session(scenario, "pid", (f"M303 E0 S{TARGET_C} C{M303_CYCLES}",), noise_lsb)
    gains = dict(DEFINE.findall(replies))
    if set(gains) != {"p", "i", "d"}:
        raise ValueError("M303 did not finish: " + " | ".join(replies.splitlines()[-3:]))
    return PidGains(float(gains["p"]), float(gains["i"]), float(gains["d"]))


# -- 1: M306 T against the model it measures -------------------------------------------------------
def mpc_plant(constants: MpcConstants) -> dict[str, float | str]:
    """The two-node plant (twin/plants.py Lumped, Marlin's MPC model) with MPC's constants."""
    return {"preset": "hotend", "power_w": constants.heater_power_w,
            "block_heat_capacity_j_k": constants.block_heat_capacity_j_k,
            "sensor_responsiveness_per_s": constants.sensor_responsiveness_per_s,
            "ambient_xfer_w_k": constants.ambient_xfer_w_k, "fan_ambient_xfer_w_k": constants.fan_ambient_xfer_w_k,
            "filament_heat_capacity_j_k_mm": constants.filament_heat_capacity_j_k_mm}


def fitted_model(capture: str) -> MpcConstants:
    """``twin-fit CAPTURE``'s two-node fit, through the M306 line it prints."""
    done = subprocess.run([sys.executable, "-m", "tools.cli.fit", str(hardware_logs_dir() / capture)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ValueError(f"twin-fit {capture} failed: {done.stderr.strip()}")
    return mpc_constants_from_text(done.stdout)


def accuracy_rows() -> list[str]:
    spec = SPECS["hotend"]
    assert isinstance(spec, Lumped)  # the hotend preset is Marlin's MPC model
    models: list[tuple[str, MpcConstants, dict[str, float | str]]] = [("`hotend` preset (Configuration.h)", MpcConstants.from_m306(
        spec.power_w, spec.block_heat_capacity_j_k, spec.sensor_responsiveness_per_s, spec.ambient_xfer_w_k,
        spec.fan_ambient_xfer_w_k, spec.filament_heat_capacity_j_k_mm), {"preset": "hotend"})]
    models += [(f"twin-fit `{capture}`", model, mpc_plant(model)) for capture in CAPTURES
               for model in [fitted_model(capture)]]
    rows = []
    for label, model, plant in models:
        found = m306_t(plant_scenario(plant))
        cells = [f"{getattr(model, name):.4g} / {getattr(found, name):.4g} ({_pct(found, model, name)})"
                 for _, name in CONSTANTS]
        rows.append(f"| {label} | " + " | ".join(cells) + f" | {1 / model.sensor_responsiveness_per_s:.3g} |")
    return rows


def _pct(found: MpcConstants, model: MpcConstants, name: str) -> str:
    return f"{100 * (getattr(found, name) - getattr(model, name)) / getattr(model, name):+.1f} %"


# -- 2: PID against MPC -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Hold:
    overshoot_c: float
    time_to_band_s: float | None
    low_c: float  # reading - target over the hold, lowest and highest
    high_c: float
    mean_c: float
    trip: str | None  # the thermal protection error that halted the board, with its time

    @property
    def holds(self) -> bool:
        return self.trip is None and max(abs(self.low_c), abs(self.high_c)) <= HOLD_BAND_C

    def cells(self) -> list[str]:
        band = "-" if self.time_to_band_s is None else f"{self.time_to_band_s:.1f}"
        hold = [f"{self.low_c:+.2f} .. {self.high_c:+.2f}", f"{self.mean_c:+.2f}"] if self.trip is None \
            else [f"halted: {self.trip}", "-"]
        return [f"{self.overshoot_c:.2f}", band, *hold, "yes" if self.holds else "no"]


def heat_hold(firmware: str, noise_lsb: float, *, gains: PidGains | None = None,
              model: MpcConstants | None = None) -> Hold:
    """twin-sim --scenario heat_hold --plant hotend_cartridge --no-bed --firmware F [--gains | --mpc-from]."""
    scenario = with_overrides(scenario_for("heat_hold"), plant={"hotend": {"preset": PLANT}},
                              gains=None if gains is None else {"hotend": vars(gains)})
    controllers = [] if model is None else [lambda: MpcController(model)]
    twin = build_twin(scenario, firmware, controllers=controllers, with_bed=False, noise_lsb=noise_lsb)
    result = twin.run(scenario.duration_s)
    run, trips = result.hotend, result.protection_trips()
    metrics = run.metrics()
    assert not isinstance(metrics, list)  # one twin, one lane
    hold = run.t_s >= HOLD_FROM_S
    error_c = run.measured_c[hold] - TARGET_C
    trip = f"{trips[0][1]} at {trips[0][0]:.0f} s" if trips else None
    return Hold(metrics.overshoot_c or 0.0, metrics.time_to_band_s, float(error_c.min()), float(error_c.max()),
                float(np.mean(error_c)), trip)


def tuned_model() -> tuple[MpcConstants, str]:
    """``twin-tune TUNE_ARGS``'s answer (the ensemble, 1 LSB of noise, the proof and its verdict), through the
    M306 line a user would paste, and which it is: new constants, or M306 T's kept."""
    from tools.tuning.problems import build_problem, preset_source
    from tools.tuning.tuner import proven, tune

    problem = build_problem(preset_source(PLANT), TARGET_C, controller="mpc")
    proof = proven(tune(problem, seed=int(TUNE_ARGS[-1])))
    chosen = proof.answer or proof.yours
    c, r, a, f = (float(v) for v in chosen.params)
    kind = "M306 T's kept: nothing beats them on every plant" if proof.answer is None else \
        f"new: {proof.verdict.why}"
    return MpcConstants.from_m306(DEFAULT_CONSTANTS.heater_power_w, c, r, a, f,
                                  DEFAULT_CONSTANTS.filament_heat_capacity_j_k_mm), kind


def comparison_rows() -> list[str]:
    rows = []
    cartridge = plant_scenario({"preset": PLANT})
    tuned, kind = tuned_model()
    for noise in NOISES_LSB:
        gains, model = m303(cartridge, noise), m306_t(cartridge, noise)
        for label, hold in ((f"PID, M303 gains Kp {gains.kp:g} Ki {gains.ki:g} Kd {gains.kd:g}",
                             heat_hold("pid", noise, gains=gains)),
                            (f"MPC, M306 T: `{model.m306()}`", heat_hold("mpc", noise, model=model)),
                            (f"MPC, twin-tune ({kind}): `{tuned.m306()}`", heat_hold("mpc", noise, model=tuned))):
            rows.append(f"| {noise:g} | {label} | " + " | ".join(hold.cells()) + " |")
    return rows


def markdown() -> str:
    lines = [f"Written by `{COMMAND}`.", "",
             "M306 T (through the serial layer, from ambient) on two-node plants: each constant as the plant has "
             "it / as M306 T found it (error). The sensor lag 1/R sets how well Marlin's method can do.", "",
             "| plant | C J/K | R 1/s | A W/K | F W/K | sensor lag 1/R s |", "|---|---|---|---|---|---|",
             *accuracy_rows(), "",
             f"`{PLANT}` at {TARGET_C} C (heat_hold, 600 s, no bed), each firmware tuned by its own autotune on the "
             "same twin, with the ADC noise of its row; the last row of each noise level runs the constants of "
             f"`twin-tune {' '.join(TUNE_ARGS)}` (tuned once, on the preset's ensemble with 1 LSB of noise, proven). Overshoot and the time to within 2 C on the firmware's "
             f"reading; the hold is reading - target over {HOLD_FROM_S:g}..600 s; holds: within {HOLD_BAND_C:g} C. "
             f"A noiseless reading steps by one ADC count, {B3950_TABLE.count_c(TARGET_C):.2f} C at {TARGET_C} C.",
             "", "| noise LSB | firmware and its tuning | overshoot C | to +-2 C s | hold C | mean C | holds |",
             "|---|---|---|---|---|---|---|", *comparison_rows()]
    return "\n".join(lines) + "\n"


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.docs.mpc_report", description=__doc__.splitlines()[0])
    parser.add_argument("--doc", type=doc_page(BEGIN, END), help="rewrite the generated MPC section of this file (docs/firmware.md)")
    return parser


def run(args: argparse.Namespace) -> int:
    body = markdown()
    if args.doc is not None:
        write_section(args.doc, body, BEGIN, END)
    print(body, end="")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(), run, argv)


if __name__ == "__main__":
    sys.exit(main())
