"""The referee's cases, their inputs and the port's side: a case is a heater config, a law and a list
of steps, run through firmware_port/klipper with klippy 0.12's switches (KLIPPY_0_12) and recorded
exactly as klippy_driver.py records klippy's own code.

Steps: ["S", target] set_temp; ["T", read_time, temp] a sensor report (temperature_callback);
["P", read_time, value] a direct set_pwm; ["C", eventtime] verify_heater's check_event.
"""

from __future__ import annotations

import math

import numpy as np

from firmware_port.klipper import (
    KLIPPY_0_12,
    CommandError,
    ControlAutoTune,
    ControlBangBang,
    ControlPID,
    HeaterConfig,
    HeaterFault,
    KlipperHeater,
    VerifyHeater,
)
from firmware_port.klipper.heater import REPORT_TIME
from twin.klipper_twin import ATMEGA2560, HeaterSetup, KlipperTwin
from twin.plants import make_plant

LAWS = ("pid", "watermark", "autotune", "verify", "pwm")


def control_state(control) -> list:
    if isinstance(control, ControlPID):
        return [control.prev_temp_deriv, control.prev_temp_integ]
    if isinstance(control, ControlBangBang):
        return [control.heating]
    return [control.heating, control.peak, control.peak_time, len(control.peaks)]


def run_port(case: dict) -> dict:
    """The port's records for one case (see klippy_driver.run_case)."""
    config = case["config"]
    heater = KlipperHeater(HeaterConfig(
        config["name"], config["min_temp"], config["max_temp"], control=config["control"], pid_kp=config["kp"],
        pid_ki=config["ki"], pid_kd=config["kd"], max_delta_c=config["max_delta"], max_power=config["max_power"],
        smooth_time_s=config["smooth_time"], **KLIPPY_0_12))
    check = VerifyHeater(heater)
    tune = None
    if case["law"] == "autotune":
        tune = ControlAutoTune(heater, case["target"])
        heater.set_control(tune)
    records: list = []
    for step in case["steps"]:
        kind = step[0]
        if kind == "S":
            try:
                heater.set_target(step[1])
                records.append(None)
            except CommandError as error:
                records.append(str(error))
        elif kind in ("T", "P"):
            if kind == "T":
                event = heater.temperature_callback(step[1], step[2])
            else:
                event = heater.set_pwm(step[1], step[2])
            sent = [] if event is None else [[event.time_s, event.value]]
            records.append([sent, heater.last_pwm_value, heater.next_pwm_time, heater.smoothed_temp,
                            heater.last_temp, heater.check_busy(step[1])] + control_state(heater.control))
        else:
            records.append(_check(check, heater, step[1]))
    result: dict = {"records": records}
    if tune is not None:
        result["peaks"] = [list(p) for p in tune.peaks]
        result["pwm_samples"] = [list(p) for p in tune.pwm_samples]
        result["busy"] = tune.check_busy(0.0, 0.0, 0.0)
        result["final"] = list(tune.calc_final_pid()) if len(tune.peaks) > 4 else None
    return result


def _check(check: VerifyHeater, heater: KlipperHeater, eventtime: float) -> list:
    try:
        waketime, fault = check.check_event(eventtime), None
    except HeaterFault as error:
        waketime, fault = None, str(error)
    goal = None if math.isinf(check.goal_systime) else check.goal_systime
    return [waketime, fault, check.error, check.approaching_target, check.starting_approach, check.goal_temp, goal,
            list(heater.get_temp(eventtime))]


def readings(case: dict) -> int:
    return sum(step[0] == "T" for step in case["steps"])


# -- the inputs ----------------------------------------------------------------------------------------
def config_for(law: str, rng: np.random.Generator) -> dict:
    """A heater section: PID gains, limits, max_power and smooth_time drawn around real configs."""
    name = "heater_bed" if law == "watermark" and rng.random() < 0.5 else "extruder"
    return {"name": name, "control": "watermark" if law == "watermark" else "pid", "min_temp": 0.0,
            "max_temp": 300.0, "kp": float(rng.uniform(5, 60)), "ki": float(rng.uniform(0, 5)),
            "kd": float(rng.uniform(0, 300)), "max_delta": float(rng.uniform(0.5, 5)),
            "max_power": float(rng.choice([1.0, rng.uniform(0.2, 1.0)])),
            "smooth_time": float(rng.choice([1.0, 2.0, rng.uniform(0.1, 3.0)]))}


def twin_temps(law: str, target_c: float, duration_s: float) -> list[tuple[float, float]]:
    """(read_time, temp) of a KlipperTwin run on the stock hotend: a heat-up and hold, or PID_CALIBRATE."""
    config = HeaterConfig("extruder", 0.0, 300.0, pid_kp=22.2, pid_ki=1.08, pid_kd=114.0, **KLIPPY_0_12)
    twin = KlipperTwin([HeaterSetup(config, make_plant("hotend_stock"), noise_lsb=0.7)], mcu=ATMEGA2560)
    if law == "autotune":
        twin.pid_calibrate("extruder", target_c)
    else:
        twin.set_target("extruder", target_c)
        twin.run_until(duration_s)
    return [(row.t_s, row.temp_c) for row in twin.reports("extruder")]


def walk_temps(rng: np.random.Generator, n: int, start_s: float) -> list[tuple[float, float]]:
    """A random walk of readings every ~0.3 s (jittered, sometimes a gap), temperatures -5..320 C."""
    dt = REPORT_TIME + rng.normal(0, 0.003, n)
    dt[rng.random(n) < 0.02] *= rng.uniform(2, 30)  # lost reports and stale sensors
    times = start_s + np.cumsum(np.abs(dt))
    temps = np.clip(rng.uniform(20, 250) + np.cumsum(rng.normal(0, 1.5, n)), -5, 320)
    return list(zip(times.tolist(), temps.tolist()))


def build_case(law: str, temps: list[tuple[float, float]], rng: np.random.Generator,
               tune_target_c: float | None = None) -> dict:
    """Steps over the readings: target changes now and then, verify checks every 1 s, direct set_pwm
    calls (law "pwm"), in time order."""
    target = float(rng.choice([0.0, 60.0, 150.0, 200.0, 245.0]))
    steps: list[list] = [["S", target]]
    next_check = temps[0][0]
    for read_time, temp in temps:
        if rng.random() < 0.01:
            target = float(rng.choice([0.0, 60.0, 150.0, 200.0, 245.0, 320.0]))  # 320: out of range, refused
            steps.append(["S", target])
        if law == "verify":
            while next_check <= read_time:
                steps.append(["C", next_check])
                next_check += 1.0
        if law == "pwm":
            steps.append(["P", read_time, float(rng.choice([0.0, 0.03, 0.049, 0.05, 0.5, 1.0, rng.random()]))])
        steps.append(["T", read_time, temp])
    tune_target_c = float(rng.uniform(60, 250)) if tune_target_c is None else tune_target_c
    return {"law": law, "config": config_for(law, rng), "target": tune_target_c, "steps": steps}


def cases_for(law: str, min_readings: int, seed: int) -> list[dict]:
    """Twin runs (a heat-up and hold at 200 C, PID_CALIBRATE at 200 C) then random walks, until the
    cases hold at least min_readings sensor reports."""
    rng = np.random.default_rng(seed)
    cases = [build_case(law, twin_temps(law, 200.0, 600.0), rng, tune_target_c=200.0)]
    while sum(readings(c) for c in cases) < min_readings:
        cases.append(build_case(law, walk_temps(rng, int(rng.integers(50, 800)), float(rng.uniform(0, 500))), rng))
    return cases
