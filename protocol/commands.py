"""Marlin 2.1's G-code handlers for a printer whose only hardware is its heaters.

A handler takes the printer and the parsed command. It returns None when done (the printer
sends ``ok``), ``NO_OK`` when it printed its own ``ok`` (M105), or a generator when the
command takes time: it yields the tick it wants to be resumed at and returns False to suppress
the ``ok`` (a kill). Sources (Marlin 2.1.x): Marlin/src/gcode/temp/M104_M109.cpp, M140_M190.cpp,
M105.cpp, M303.cpp, Marlin/src/gcode/queue.cpp, Marlin/src/module/temperature.cpp, core/language.h.
"""

from __future__ import annotations

import logging

from firmware_port.fixed import wrap_s32
from firmware_port.marlin.board import BED_CHANNEL, HOTEND_CHANNEL
from firmware_port.marlin.constants import (
    PREHEAT_1_TEMP_BED_C,
    PREHEAT_1_TEMP_HOTEND_C,
    TEMP_BED_HYSTERESIS_C,
    TEMP_HYSTERESIS_C,
)
from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX, PidGains
from firmware_port.marlin.serial import format_float
from protocol.context import PrinterContext
from protocol.gcode import Command, float_to_u32, unknown_command_text
from protocol.mpc_commands import MPC_HANDLERS, load_constants, settings_report, stored_constants
from protocol.settings import EEPROM_VERSION, CrcMismatch, Settings, VersionMismatch, crc16, load_image

NO_OK = object()

SHORT_BUILD_VERSION = "2.1.2.1"
FIRMWARE_NAME = f"Marlin {SHORT_BUILD_VERSION} (heater-twin digital twin)"
UUID = "cede2a2f-41a2-4748-9b12-c55c62f367ff"
# M115 capabilities with the defaults of a Marlin 2.1 build that has heaters and nothing else.
CAPABILITIES = (
    ("SERIAL_XON_XOFF", 0), ("BINARY_FILE_TRANSFER", 0), ("EEPROM", 1), ("VOLUMETRIC", 1),
    ("AUTOREPORT_POS", 0), ("AUTOREPORT_TEMP", 1), ("PROGRESS", 0), ("PRINT_JOB", 1),
    ("AUTOLEVEL", 0), ("RUNOUT", 0), ("Z_PROBE", 0), ("LEVELING_DATA", 0), ("BUILD_PERCENT", 0),
    ("SOFTWARE_POWER", 0), ("TOGGLE_LIGHTS", 0), ("CASE_LIGHT_BRIGHTNESS", 0), ("EMERGENCY_PARSER", 0),
    ("HOST_ACTION_COMMANDS", 0), ("PROMPT_SUPPORT", 0), ("SDCARD", 0), ("REPEAT", 0), ("SD_WRITE", 0),
    ("AUTOREPORT_SD_STATUS", 0), ("LONG_FILENAME", 0), ("EXTENDED_M20", 0), ("THERMAL_PROTECTION", 1),
    ("MOTION_MODES", 0), ("ARCS", 0), ("BABYSTEPPING", 0), ("CHAMBER_TEMPERATURE", 0),
    ("COOLER_TEMPERATURE", 0), ("MEATPACK", 0), ("CONFIG_EXPORT", 0),
)
TEMP_RESIDENCY_TIME_MS = 10_000  # TEMP_RESIDENCY_TIME / TEMP_BED_RESIDENCY_TIME
TEMP_WINDOW_C = 1  # TEMP_WINDOW / TEMP_BED_WINDOW
MIN_COOLING_SLOPE_C = {HOTEND_CHANNEL: 1.5, BED_CHANNEL: 1.0}  # MIN_COOLING_SLOPE_DEG(_BED)
MIN_COOLING_SLOPE_MS = 60_000  # MIN_COOLING_SLOPE_TIME(_BED)
WAIT_HYSTERESIS_C = {HOTEND_CHANNEL: TEMP_HYSTERESIS_C, BED_CHANNEL: TEMP_BED_HYSTERESIS_C}
AUTOREPORT_MAX_S = 60
DEFAULT_KEEPALIVE_S = 2  # DEFAULT_KEEPALIVE_INTERVAL
DWELL_MAX_MS = 1 << 31  # dwell(): PENDING() compares as int32
STR_INVALID_EXTRUDER = "Invalid extruder"
STR_PID_BAD_HEATER_ID = "PID Autotune failed! Bad heater id"
STR_ERR_EEPROM_WRITE = "Error writing to EEPROM!"  # core/language.h
LOG = logging.getLogger(__name__)


def banner(p: PrinterContext, power_up: bool) -> str:
    """setup(): start, the reset reason, the version, memory, then the settings (EEPROM first_load)."""
    lines = ["start", "PowerUp" if power_up else " External Reset", f"Marlin {SHORT_BUILD_VERSION}",
             "echo: Last Updated: 2026-11-21 | Author: (heater-twin)",
             "echo: Free Memory: 1024  PlannerBufferBytes: 1232"]
    return "\n".join(lines) + "\n" + _load_settings(p) + _settings_report(p)


# -- temperatures ---------------------------------------------------------------------------
def _target_extruder_ok(p: PrinterContext, cmd: Command) -> bool:
    """get_target_extruder_from_command(): only T0 exists."""
    if cmd.has("T") and cmd.value_int("T", 0) != 0:
        p.write(f"echo:M{cmd.code} {STR_INVALID_EXTRUDER} {cmd.value_int('T', 0)}\n")
        return False
    return True


def m104(p: PrinterContext, cmd: Command):
    """Set the hotend target (S or R), clamped by the board to maxtemp - 15."""
    if _target_extruder_ok(p, cmd) and (cmd.has("S") or cmd.has("R")):
        p.twin.board.set_target(HOTEND_CHANNEL, cmd.value_celsius("S" if cmd.has("S") else "R", 0))


def m109(p: PrinterContext, cmd: Command):
    """Set the hotend target and wait: S waits only when heating, R either way."""
    if not _target_extruder_ok(p, cmd) or not (cmd.has("S") or cmd.has("R")):
        return None
    p.twin.board.set_target(HOTEND_CHANNEL, cmd.value_celsius("S" if cmd.has("S") else "R", 0))
    return wait_for_heater(p, HOTEND_CHANNEL, no_wait_for_cooling=cmd.has("S"))


def _has_bed(p: PrinterContext, cmd: Command) -> bool:
    """M140/M190 exist only with a heated bed (HAS_HEATED_BED); without one Marlin does not know them."""
    if p.twin.board.bed is None:
        p.write(unknown_command_text(cmd))
        return False
    return True


def m140(p: PrinterContext, cmd: Command):
    """Set the bed target."""
    if _has_bed(p, cmd) and cmd.has("S"):
        p.twin.board.set_target(BED_CHANNEL, cmd.value_celsius("S", 0))


def m190(p: PrinterContext, cmd: Command):
    """Set the bed target and wait (S: only when heating)."""
    if not _has_bed(p, cmd) or not (cmd.has("S") or cmd.has("R")):
        return None
    p.twin.board.set_target(BED_CHANNEL, cmd.value_celsius("S" if cmd.has("S") else "R", 0))
    return wait_for_heater(p, BED_CHANNEL, no_wait_for_cooling=cmd.has("S"))


def _residency_start(start_ms: int, diff_c: float, now_ms: int, first_loop: bool, channel: int) -> int:
    """When the residency count started (0: not started): it starts inside TEMP_WINDOW (a third
    of the residency early on the first loop) and restarts when the temperature leaves the
    hysteresis band."""
    if not start_ms:
        if diff_c < TEMP_WINDOW_C:
            return now_ms + (TEMP_RESIDENCY_TIME_MS // 3 if first_loop else 0)
        return 0
    return now_ms if diff_c > WAIT_HYSTERESIS_C[channel] else start_ms


def wait_for_heater(p: PrinterContext, channel: int, no_wait_for_cooling: bool):
    """wait_for_hotend / wait_for_bed: 1 s reports with W:, residency 10 s within 1 C, M108 breaks."""
    board = p.twin.board
    target_c = -1.0  # float target_temp = -1.0: a target of -1 is never seen as a change
    wants_to_cool = False
    residency_start_ms = next_temp_ms = next_cool_check_ms = 0
    old_temp_c = 9999.0
    first_loop = True
    p.wait_for_heatup = True
    while True:
        now = board.now_ms
        temp_c = board.temp_c(channel)
        if target_c != board.target_c(channel):
            target_c = board.target_c(channel)
            wants_to_cool = target_c < temp_c
            if no_wait_for_cooling and wants_to_cool:
                break
        if now >= next_temp_ms:
            next_temp_ms = now + 1000
            left = "?" if not residency_start_ms else str((TEMP_RESIDENCY_TIME_MS - (now - residency_start_ms)) // 1000)
            p.write(f"{board.heater_states()} W:{left}\n")
        wake = min(p.next_reading_tick(), p.after_ms(next_temp_ms - now))
        if residency_start_ms:
            wake = min(wake, p.after_ms(residency_start_ms + TEMP_RESIDENCY_TIME_MS - now))
        yield wake  # idle(): the clock runs, the board reads and controls
        if board.halted:
            return False
        now = board.now_ms
        temp_c = board.temp_c(channel)
        residency_start_ms = _residency_start(residency_start_ms, abs(target_c - temp_c), now, first_loop, channel)
        if wants_to_cool and (not next_cool_check_ms or now >= next_cool_check_ms):
            if old_temp_c - temp_c < MIN_COOLING_SLOPE_C[channel]:
                break
            next_cool_check_ms = now + MIN_COOLING_SLOPE_MS
            old_temp_c = temp_c
        first_loop = False
        residency_pending = not residency_start_ms or now < residency_start_ms + TEMP_RESIDENCY_TIME_MS
        if not (p.wait_for_heatup and residency_pending):
            break
    p.wait_for_heatup = False
    return None


def m105(p: PrinterContext, cmd: Command):
    """Report temperatures: one line that is its own ok."""
    if _target_extruder_ok(p, cmd):
        p.write(f"ok{p.twin.board.heater_states()}\n")
        return NO_OK
    return None


def m155(p: PrinterContext, cmd: Command):
    """Auto-report temperatures every S seconds (parser.value_byte(), S0 off, at most 60)."""
    if cmd.has_value("S"):
        p.autoreport_s = min(cmd.value_byte("S"), AUTOREPORT_MAX_S)
        p.autoreport_tick = p.after_ms(p.autoreport_s * 1000)
        p.autoreport_wall_s = p.wall_s() + p.autoreport_s


def m106(p: PrinterContext, cmd: Command):
    """Part fan speed S0..255 (255 without S); P0 is the only fan."""
    if cmd.value_int("P", 0) == 0:
        p.twin.board.fan_speed = min(max(cmd.value_int("S", 255), 0), 255)


def m107(p: PrinterContext, cmd: Command):
    """Part fan off."""
    if cmd.value_int("P", 0) == 0:
        p.twin.board.fan_speed = 0


# -- PID --------------------------------------------------------------------------------------
def _pid_text(gains: PidGains) -> str:
    return f"P{format_float(gains.kp)} I{format_float(gains.ki)} D{format_float(gains.kd)}"


def _pid_line(code: str, gains: PidGains) -> str:
    return f"echo:  {code} {_pid_text(gains)}\n"


def _set_pid(p: PrinterContext, channel: int, cmd: Command, code: str):
    """M301 / M304: set P, I, D (user units) or report them; Unknown without PID on that heater.

    Marlin stores whatever float it is sent, negative gains too (gcode/config/M301.cpp), and so does
    the twin, within the fixed-point port's range (pid.py KP_MAX...): beyond it the gain is clamped
    and an echo line says so. A controller that refuses a gain (the fuzzy-PID's base gains must be
    >= 0) keeps its gains, and the echo line says why.
    """
    board = p.twin.board
    if not board.has_gains(channel):
        p.write(unknown_command_text(cmd))
        return None
    g = board.gains(channel)
    if not any(cmd.has(k) for k in "PID"):
        p.write(_pid_line(code, g))
        return None
    asked = (cmd.value_float("P", g.kp), cmd.value_float("I", g.ki), cmd.value_float("D", g.kd))
    gains = PidGains.clamped(*asked)
    try:
        board.set_gains(channel, gains)
    except ValueError as exc:
        p.write(f"echo:{code} refused: {exc}\n")
        return None
    if (gains.kp, gains.ki, gains.kd) != asked:
        p.write(f"echo:{code} gains clamped to the twin's range (|P| <= {KP_MAX:g}, |I| <= {KI_MAX:g}, "
                f"|D| <= {KD_MAX:g}): {_pid_text(gains)}\n")
    return None


def m301(p: PrinterContext, cmd: Command):
    """Hotend PID gains."""
    if cmd.value_int("E", 0) != 0:
        p.write(f"Error:{STR_INVALID_EXTRUDER}\n")
        return None
    return _set_pid(p, HOTEND_CHANNEL, cmd, "M301")


def m304(p: PrinterContext, cmd: Command):
    """Bed PID gains."""
    return _set_pid(p, BED_CHANNEL, cmd, "M304")


def m303(p: PrinterContext, cmd: Command):
    """PID autotune: E0 hotend, E-1 bed; S target, C cycles (5), U1 applies the result."""
    board = p.twin.board
    heater_id = cmd.value_int("E", 0)
    channel = {0: HOTEND_CHANNEL, -1: BED_CHANNEL}.get(heater_id)
    if channel is None or not board.can_autotune(channel):
        p.write(STR_PID_BAD_HEATER_ID + "\n")
        return None
    default_c = PREHEAT_1_TEMP_BED_C if channel == BED_CHANNEL else PREHEAT_1_TEMP_HOTEND_C
    board.start_autotune(channel, cmd.value_celsius("S", default_c), cmd.value_int("C", 5), apply=cmd.value_bool("U"))
    if board.autotune is None:  # refused: too high
        return None
    return _autotune_wait(p)


def _autotune_wait(p: PrinterContext):
    """M303's loop is its own: no idle(), so no busy lines or auto-reports meanwhile."""
    board = p.twin.board
    p.idle_calls = False
    while board.autotune is not None and not board.halted:
        yield p.next_reading_tick()
    p.idle_calls = True
    return False if board.halted else None


# -- settings -----------------------------------------------------------------------------------
def _hardcoded_settings(p: PrinterContext) -> Settings:
    """Configuration.h's settings (M502, or no valid EEPROM): the gains the build came with."""
    gains = p.twin.board.default_gains + [None]
    defaults = Settings()
    return Settings(gains[HOTEND_CHANNEL] or defaults.hotend, gains[BED_CHANNEL] or defaults.bed)


def _current_settings(p: PrinterContext) -> Settings:
    board = p.twin.board
    pids = [board.gains(c) if board.has_gains(c) else None for c in range(len(board.heaters))] + [None]
    defaults = _hardcoded_settings(p)
    return Settings(pids[HOTEND_CHANNEL] or defaults.hotend, pids[BED_CHANNEL] or defaults.bed,
                    stored_constants(board))


def _apply_settings(p: PrinterContext, settings: Settings) -> None:
    board = p.twin.board
    for channel, gains in ((HOTEND_CHANNEL, settings.hotend), (BED_CHANNEL, settings.bed)):
        if board.can_autotune(channel):
            board.set_gains(channel, gains)
    load_constants(board, settings.hotend_mpc)


def _load_settings(p: PrinterContext) -> str:
    """settings.load(): the stored image if it is valid, else the defaults after Marlin's line for
    what is wrong (module/settings.cpp _load(): the version, then the CRC). A file the EEPROM
    refuses to read now (a link, a device) reads as a blank EEPROM; the log says why."""
    try:
        data = p.eeprom.read()
    except OSError as exc:
        LOG.warning("settings not read: %s", exc)
        data = b""
    if data is None:
        _apply_settings(p, _hardcoded_settings(p))
        return "echo:Hardcoded Default Settings Loaded\n"
    try:
        settings, payload = load_image(data)
    except VersionMismatch as exc:
        why = f"echo:EEPROM version mismatch (EEPROM={exc.shown} Marlin={EEPROM_VERSION})\n"
    except CrcMismatch as exc:
        why = f"Error:EEPROM CRC mismatch - (stored) {exc.stored} != {exc.calculated} (calculated)!\n"
    else:
        _apply_settings(p, settings)
        return f"echo:{EEPROM_VERSION} stored settings retrieved ({len(payload)} bytes; crc {crc16(payload)})\n"
    _apply_settings(p, _hardcoded_settings(p))
    return why + "echo:Hardcoded Default Settings Loaded\n"


def _settings_report(p: PrinterContext) -> str:
    """M503: the PID sections of Marlin's settings report."""
    board = p.twin.board
    text = ""
    for channel, code, title in ((HOTEND_CHANNEL, "M301", "Hotend PID"), (BED_CHANNEL, "M304", "Bed PID")):
        if board.can_autotune(channel):
            text += f"echo:; {title}:\n" + _pid_line(code, board.gains(channel))
    return text + settings_report(board)


def m500(p: PrinterContext, cmd: Command):
    """settings.save(). A failed write (or one the EEPROM refuses: a link, a file M500 did not
    write) prints STR_ERR_EEPROM_WRITE (the HAL's write_data), and the report follows it as on the
    board: Marlin 2.1's EEPROM_WRITE ignores write_data's result. The log says why."""
    settings = _current_settings(p)
    try:
        p.eeprom.write(settings.to_bytes())
    except OSError as exc:
        LOG.warning("M500 not written: %s", exc)
        p.write(f"echo:{STR_ERR_EEPROM_WRITE}\n")
    payload = settings.payload()
    p.write(f"echo:Settings Stored ({len(payload)} bytes; crc {crc16(payload)})\n")


def m501(p: PrinterContext, cmd: Command):
    p.write(_load_settings(p))


def m502(p: PrinterContext, cmd: Command):
    _apply_settings(p, _hardcoded_settings(p))
    p.write("echo:Hardcoded Default Settings Loaded\n")


def m503(p: PrinterContext, cmd: Command):
    p.write(_settings_report(p))


# -- host protocol -------------------------------------------------------------------------------
def m108(p: PrinterContext, cmd: Command):
    """Break a heat wait: already acted on when the line arrived."""


def m113(p: PrinterContext, cmd: Command):
    """Host keepalive interval (S0 off, at most 60); report it without S."""
    if cmd.has("S"):
        p.keepalive_s = min(cmd.value_byte("S", DEFAULT_KEEPALIVE_S), 60)  # parser.byteval('S', ...)
    else:
        p.write(f"echo:M113 S{p.keepalive_s}\n")


def m115(p: PrinterContext, cmd: Command):
    """Firmware name and capabilities."""
    p.write(f"FIRMWARE_NAME:{FIRMWARE_NAME} SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
            f"MACHINE_TYPE:heater-twin EXTRUDER_COUNT:1 UUID:{UUID}\n")
    p.write("".join(f"Cap:{name}:{value}\n" for name, value in CAPABILITIES))


def m110(p: PrinterContext, cmd: Command):
    """Set the line number (the line layer already took an N'd M110)."""
    if cmd.has("N"):
        p.reader.last_n = cmd.value_long("N", 0)


def m999(p: PrinterContext, cmd: Command):
    """Restart after a stop(): clear it and ask for the next line (a kill needs a reset)."""
    p.reader.stopped = False
    p.write(f"Resend: {wrap_s32(p.reader.last_n + 1)}\n")


# -- motion ----------------------------------------------------------------------------------------
def _axes(cmd: Command) -> dict[str, float]:
    return {k: cmd.value_float(k, 0.0) for k in "XYZEF" if cmd.has(k)}


def g0_g1(p: PrinterContext, cmd: Command):
    """A move: queued in the planner, waiting for a free block first (that is when time runs)."""
    if not p.planner.full:
        p.write(p.planner.move(_axes(cmd)))
        return None
    return _move_when_free(p, _axes(cmd))


def _next_block_end(p: PrinterContext) -> int:
    """The tick the head block ends: a waiting command sleeps until then, not a tick at a time."""
    return p.now_tick + (p.planner.ticks_to_next_change() or 1)


def _move_when_free(p: PrinterContext, axes: dict[str, float]):
    while p.planner.full:
        yield _next_block_end(p)
    p.write(p.planner.move(axes))


def g4(p: PrinterContext, cmd: Command):
    """Dwell P milliseconds (parser.value_millis(), a uint32) or S seconds (value_millis_from_seconds(),
    the float times 1000 cast to uint32; S wins when both are given), after the moves."""
    ms = 0
    if cmd.has_value("P"):
        ms = cmd.value_ulong("P")
    if cmd.has_value("S"):
        ms = float_to_u32(cmd.value_float("S") * 1000.0)
    return _dwell(p, ms)


def dwell_span_ms(ms: int) -> int:
    """How long MarlinCore.cpp dwell(ms) waits: ``time += millis(); while (PENDING(millis(), time))``
    with PENDING a signed 32-bit difference, so a uint32 beyond 2^31 ms has already passed."""
    return ms if ms <= DWELL_MAX_MS else 0


def _dwell(p: PrinterContext, ms: int):
    yield from _synchronize(p)
    end = p.after_ms(dwell_span_ms(ms))
    while p.now_tick < end:
        yield end


def _synchronize(p: PrinterContext):
    """planner.synchronize(): idle until every block has run and a quickstop's cleaning window is over."""
    while p.planner.busy:
        yield _next_block_end(p)


def m410(p: PrinterContext, cmd: Command):
    """quickstop_stepper() once more (the line's arrival ran it first): the moves are dropped, the
    position is where the steppers stopped, and the ok waits out the cleaning window."""
    p.planner.quickstop()
    return _synchronize(p)


def m400(p: PrinterContext, cmd: Command):
    """Wait for the moves to finish."""
    return _synchronize(p) if p.planner.busy else None


def g92(p: PrinterContext, cmd: Command):
    p.planner.set_position(_axes(cmd))


def g28(p: PrinterContext, cmd: Command):
    """Home the named axes (all without X, Y or Z): nothing to move, their positions become 0 and
    the software endstops apply to them from now on."""
    p.planner.home("".join(axis for axis in "XYZ" if cmd.has(axis)))


def _mode(attr: str, value: bool):
    def handler(p, cmd: Command):
        setattr(p.planner, attr, value)

    return handler


def m114(p: PrinterContext, cmd: Command):
    """report_current_position_projected(): the position of the last move queued, then the
    planner's step counts of it (stepper.report_a_position(planner.position), int32 steps)."""
    pos, steps = p.planner.position, p.planner.steps
    p.write(f"X:{format_float(pos['X'])} Y:{format_float(pos['Y'])} Z:{format_float(pos['Z'])} "
            f"E:{format_float(pos['E'])} Count X:{steps['X']} Y:{steps['Y']} Z:{steps['Z']}\n")


def accepted(p: PrinterContext, cmd: Command):
    """Known to Marlin, nothing to do without steppers, a display or a card."""


HANDLERS = {
    ("M", 104): m104, ("M", 109): m109, ("M", 140): m140, ("M", 190): m190, ("M", 105): m105,
    ("M", 155): m155, ("M", 106): m106, ("M", 107): m107, ("M", 301): m301, ("M", 304): m304,
    ("M", 303): m303, ("M", 500): m500, ("M", 501): m501, ("M", 502): m502, ("M", 503): m503,
    ("M", 108): m108, ("M", 113): m113, ("M", 115): m115, ("M", 110): m110, ("M", 999): m999,
    ("M", 400): m400, ("M", 114): m114, ("M", 410): m410,
    ("G", 0): g0_g1, ("G", 1): g0_g1, ("G", 4): g4, ("G", 92): g92, ("G", 28): g28,
    ("G", 90): _mode("absolute_xyz", True), ("G", 91): _mode("absolute_xyz", False),
    ("M", 82): _mode("absolute_e", True), ("M", 83): _mode("absolute_e", False),
}
HANDLERS.update(MPC_HANDLERS)  # M306 on MPC builds: protocol/mpc_commands.py
HANDLERS.update({("G", code): accepted for code in (20, 21, 29)})
HANDLERS.update({("M", code): accepted for code in (17, 18, 73, 84, 92, 111, 117, 201, 203, 204, 205, 220, 221, 302)})
