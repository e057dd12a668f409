"""Runs klippy's own heater code on given readings, for the referee tests: the interpreter of the
klippy venv runs this file (it imports nothing of heater-twin), reads one JSON case per line on
stdin and writes one JSON result per line: what klippy's Heater, ControlPID, ControlBangBang,
ControlAutoTune (pid_calibrate.py) and HeaterCheck (verify_heater.py) did at each step.

klippy's objects get stand-ins for what they reach around them (config, printer, MCU pin,
sensor, reactor); the code under test is klippy's, unmodified. The step kinds and result
records are those of port_steps.py, which runs the port the same way.
"""

import json
import sys

from klippy.extras import heaters, pid_calibrate, verify_heater

NEVER = 9999999999999999.0  # klippy/reactor.py
SENTINEL = object()


class CommandError(Exception):
    pass


class Config:
    def __init__(self, printer, name, options):
        self.printer, self.name, self.options = printer, name, options

    def get_printer(self):
        return self.printer

    def get_name(self):
        return self.name

    def get(self, option, default=SENTINEL):
        return self.options.get(option, default)

    def getfloat(self, option, default=SENTINEL, minval=None, maxval=None, above=None, below=None):
        value = self.options.get(option, default)
        if value is SENTINEL:
            raise KeyError(option)
        return float(value)

    def getchoice(self, option, choices, default=SENTINEL):
        return choices[self.options.get(option, default)]


class Pwm:
    def __init__(self):
        self.sent = []

    def setup_cycle_time(self, cycle_time, hardware_pwm=False):
        pass

    def setup_max_duration(self, max_duration):
        pass

    def set_pwm(self, print_time, value):
        self.sent.append([print_time, value])

    def get_mcu(self):
        return self

    def estimated_print_time(self, eventtime):
        return eventtime  # the twin has one clock


class Sensor:
    def setup_minmax(self, min_temp, max_temp):
        pass

    def setup_callback(self, callback):
        pass

    def get_report_time_delta(self):
        return 0.300  # adc_temperature.py REPORT_TIME


class Reactor:
    NEVER = NEVER
    NOW = 0.0

    def register_timer(self, callback, waketime=NEVER):
        return None


class Printer:
    command_error = CommandError

    def __init__(self):
        self.pwm = Pwm()
        self.reactor = Reactor()
        self.heater = None
        self.shutdown_message = None

    def lookup_object(self, name):
        return self

    # 'pins', 'gcode' and 'heaters' are this object too
    def setup_pin(self, pin_type, pin):
        return self.pwm

    def register_mux_command(self, *args, **kwargs):
        pass

    def lookup_heater(self, name):
        return self.heater

    def load_object(self, config, name):
        pass

    def get_start_args(self):
        return {}

    def register_event_handler(self, event, callback):
        pass

    def get_reactor(self):
        return self.reactor

    def invoke_shutdown(self, message):
        self.shutdown_message = message


def control_state(control):
    if isinstance(control, heaters.ControlPID):
        return [control.prev_temp_deriv, control.prev_temp_integ]
    if isinstance(control, heaters.ControlBangBang):
        return [control.heating]
    return [control.heating, control.peak, control.peak_time, len(control.peaks)]


def run_case(case):
    printer = Printer()
    config = case["config"]
    options = {"min_temp": config["min_temp"], "max_temp": config["max_temp"], "heater_pin": "PA1",
               "control": config["control"], "max_power": config["max_power"], "smooth_time": config["smooth_time"],
               "pid_Kp": config["kp"], "pid_Ki": config["ki"], "pid_Kd": config["kd"], "max_delta": config["max_delta"]}
    heater = heaters.Heater(Config(printer, config["name"], options), Sensor())
    printer.heater = heater
    check = verify_heater.HeaterCheck(Config(printer, "verify_heater " + config["name"].split()[-1], {}))
    check.handle_connect()
    if case["law"] == "autotune":
        tune = pid_calibrate.ControlAutoTune(heater, case["target"])
        heater.set_control(tune)
    records = []
    for step in case["steps"]:
        kind = step[0]
        before = len(printer.pwm.sent)
        if kind == "S":
            try:
                heater.set_temp(step[1])
                records.append(None)
            except CommandError as error:
                records.append(str(error))
            continue
        if kind == "T":
            heater.temperature_callback(step[1], step[2])
        elif kind == "P":
            heater.set_pwm(step[1], step[2])
        if kind in ("T", "P"):
            sent = printer.pwm.sent[before:]
            records.append([sent, heater.last_pwm_value, heater.next_pwm_time, heater.smoothed_temp,
                            heater.last_temp, heater.check_busy(step[1])] + control_state(heater.control))
            continue
        printer.shutdown_message = None
        waketime = check.check_event(step[1])
        goal = None if check.goal_systime >= NEVER else check.goal_systime
        records.append([None if waketime >= NEVER else waketime, printer.shutdown_message, check.error,
                        check.approaching_target, check.starting_approach, check.goal_temp, goal,
                        list(heater.get_temp(step[1]))])
    result = {"records": records}
    if case["law"] == "autotune":
        result["peaks"] = [list(p) for p in tune.peaks]
        result["pwm_samples"] = [list(p) for p in tune.pwm_samples]
        result["busy"] = tune.check_busy(0.0, 0.0, 0.0)
        result["final"] = list(tune.calc_final_pid()) if len(tune.peaks) > 4 else None
    return result


def main():
    for line in sys.stdin:
        print(json.dumps(run_case(json.loads(line))), flush=True)


if __name__ == "__main__":
    main()
