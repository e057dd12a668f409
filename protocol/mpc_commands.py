"""M306 for builds with MPC on the hotend (MPCTEMP), and what M500/M501/M502/M503 carry of it.

Source: Marlin 2.1.2.1 Marlin/src/gcode/temp/M306.cpp (``M306``, ``M306_report``),
module/settings.cpp (MPC_t in the EEPROM image, the report's last section), gcode/gcode.cpp
(``report_heading``). ``M306`` alone prints ``  M306 E0 P.. C.. R.. A.. F.. H..`` (for replay: no
``echo:``); M503 prints it under ``echo:; Model predictive control:``. ``M306 T`` runs the
autotune (firmware_port/marlin/mpc_autotune.py) as M303 runs: its loop never calls idle(). On a
build without MPC, M306 is an unknown command, as in Marlin.

``mpc_constants_from_text`` reads the constants of the first M306 line in a text (twin-fit's
``Marlin:  M306 ...``, an M306 report, a G-code file), as the firmware would set them.
"""

from __future__ import annotations

import math
import re

from firmware_port.marlin.board import HOTEND_CHANNEL, MarlinBoard
from firmware_port.marlin.mpc import DEFAULT_CONSTANTS, MpcConstants, MpcController
from firmware_port.marlin.mpc_autotune import MpcAutotune
from protocol.context import PrinterContext
from protocol.gcode import Command, parse, unknown_command_text

# Configuration.h (Marlin 2.1.2.1): MPC_TUNING_POS { X_CENTER, Y_CENTER, 1.0f } on the stock
# 200 x 200 bed, MPC_TUNING_END_Z 10.0f (do_z_clearance after the tune).
MPC_TUNING_POS_MM = {"X": 100.0, "Y": 100.0, "Z": 1.0}
MPC_TUNING_END_Z_MM = 10.0
# Marlin 2.1.2.1 writes M306 E<n> into temp_hotend[n] unchecked (past the array for n > 0); the
# twin answers as bugfix-2.1.x's M306.cpp does.
STR_E_OUT_OF_RANGE = "?(E)xtruder index out of range (0-0)."
STR_MPC_REPORT_HEADING = "Model predictive control"
SET_LETTERS = "ACFPRH"  # parser.seen("ACFPRH")
_M306_LINE = re.compile(r"\bM306\b[^\r\n]*")


def hotend_mpc(board: MarlinBoard) -> MpcController | None:
    """The hotend's MPC controller, or None on a build without MPCTEMP."""
    controller = board.hotend.controller
    return controller if isinstance(controller, MpcController) else None


def set_from_command(constants: MpcConstants, cmd: Command) -> MpcConstants:
    """M306's set branch: each letter seen with a value (parser.seenval), as float32."""
    values = {letter.lower(): cmd.value_float(letter) for letter in SET_LETTERS if cmd.has_value(letter)}
    return constants.with_m306(**values)


def m306(p: PrinterContext, cmd: Command):
    """M306 T: autotune; M306 [E0] P C R A F H: set; M306 alone: report."""
    mpc = hotend_mpc(p.twin.board)
    if mpc is None:
        p.write(unknown_command_text(cmd))
        return None
    if cmd.has("T"):
        return _autotune(p)
    if not any(cmd.has(letter) for letter in SET_LETTERS):
        p.write(f"  {mpc.constants.m306()}\n")
        return None
    if cmd.value_int("E", 0) != 0:
        p.write(STR_E_OUT_OF_RANGE + "\n")
        return None
    mpc.constants = set_from_command(mpc.constants, cmd)
    return None


def _autotune(p: PrinterContext):
    """MPC_autotune(): home (the moves finish first), to the tuning position, the loops (no
    idle(): no busy lines, no auto-reports), then the Z clearance."""
    while p.planner.busy:  # gcode.home_all_axes(): planner.synchronize()
        yield p.now_tick + 1
    board = p.twin.board
    p.planner.set_position(MPC_TUNING_POS_MM)  # G28, then do_blocking_move_to(MPC_TUNING_POS)
    tune = MpcAutotune(board)
    tune.start(board.now_ms)
    board.begin_tune(tune, HOTEND_CHANNEL)
    p.idle_calls = False
    while board.autotune is not None and not board.halted:
        yield p.next_reading_tick()
    p.idle_calls = True
    if board.halted:
        return False
    p.planner.set_position({"Z": max(p.planner.position["Z"], MPC_TUNING_END_Z_MM)})
    return None


# -- the EEPROM ------------------------------------------------------------------------------------
def stored_constants(board: MarlinBoard) -> MpcConstants | None:
    """What M500 stores of MPC: the hotend's constants (None without MPC)."""
    mpc = hotend_mpc(board)
    return None if mpc is None else mpc.constants


def load_constants(board: MarlinBoard, constants: MpcConstants | None) -> None:
    """settings.load() / reset(): stored constants, or None for the build's own (M502)."""
    mpc = hotend_mpc(board)
    if mpc is not None:
        mpc.constants = mpc.defaults if constants is None else constants


def settings_report(board: MarlinBoard) -> str:
    """M503's MPC section (its last): the heading and the M306 line, each after ``echo:``."""
    mpc = hotend_mpc(board)
    if mpc is None:
        return ""
    return f"echo:; {STR_MPC_REPORT_HEADING}:\necho:  {mpc.constants.m306()}\n"


# -- an M306 line from elsewhere --------------------------------------------------------------------
def mpc_constants_from_text(text: str, defaults: MpcConstants = DEFAULT_CONSTANTS, strict: bool = False
                            ) -> MpcConstants:
    """The constants the first M306 line in ``text`` that sets any (P C R A F H) gives, applied
    to ``defaults`` as the firmware applies them; ValueError if there is none. ``strict`` (a line a
    user gives, where the firmware would take anything): ValueError naming a letter without a number
    or whose value is not finite and positive (H: >= 0)."""
    for match in _M306_LINE.finditer(text):
        cmd = parse(match.group(0))
        if any(cmd.has_value(letter) for letter in SET_LETTERS) and not cmd.has("T"):
            if strict:
                _check_values(cmd)
            return set_from_command(defaults, cmd)
    raise ValueError("no M306 line with constants (M306 P.. C.. R.. A.. F.. H..) in it")


def _check_values(cmd: Command) -> None:
    for letter in SET_LETTERS:
        if not cmd.has(letter):
            continue
        value = cmd.value_float(letter) if cmd.has_value(letter) else math.nan
        zero_ok = letter == "H"  # no filament heat capacity: a model without extrusion
        if not (math.isfinite(value) and (value >= 0.0 if zero_ok else value > 0.0)):
            raise ValueError(f"M306 {letter}{cmd.params[letter]}: {letter} must be a finite number "
                             f"{'>= 0' if zero_ok else '> 0'}")


MPC_HANDLERS = {("M", 306): m306}
