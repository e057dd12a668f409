"""The twin MCU's motion and front-panel commands, for a printer.cfg's board: src/stepper.c,
endstop.c and trsync.c as Klipper's firmware runs them, and the display and buttons it accepts.

Steppers queue moves on their carriage (axes.py); an endstop samples its pin from the clock
klippy gives, every rest_ticks, and on a match oversamples sample_count times sample_ticks apart
before it triggers its trsync, which stops the steppers linked to it and reports. The twin
samples only where the pin can change: the first clock the queued moves press the switch (its
rail through the kinematics: axes.py), a new move of a stepper on that rail, or a command to a
probe (probe.py) (the same clocks a real MCU's sampling would find). A trsync reports every report_ticks
while it can trigger, and expires at the timeout klippy keeps moving. Step moves do not take move
queue slots (the twin computes steps when asked, not one timer each). An st7920 display and
buttons are accepted: what is sent to the display is dropped, and no button is ever pressed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from protocol.klipper_mcu import dictionary as d
from protocol.klipper_mcu.axes import Carriage, Move, Switch
from protocol.klipper_mcu.codec import to_signed
from protocol.klipper_mcu.dictionary import Chip, Shutdown
from protocol.klipper_mcu.probe import Probe

if TYPE_CHECKING:
    from collections.abc import Callable

    from protocol.klipper_mcu.board import TwinBoard
    from protocol.klipper_mcu.lateness import Lateness

COMMANDS = (
    "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u",
    "queue_step oid=%c interval=%u count=%hu add=%hi",
    "set_next_step_dir oid=%c dir=%c",
    "reset_step_clock oid=%c clock=%u",
    "stepper_get_position oid=%c",
    "stepper_stop_on_trigger oid=%c trsync_oid=%c",
    "config_endstop oid=%c pin=%c pull_up=%c",
    "endstop_home oid=%c clock=%u sample_ticks=%u sample_count=%c rest_ticks=%u pin_value=%c trsync_oid=%c"
    " trigger_reason=%c",
    "endstop_query_state oid=%c",
    "config_trsync oid=%c",
    "trsync_start oid=%c report_clock=%u report_ticks=%u expire_reason=%c",
    "trsync_set_timeout oid=%c clock=%u",
    "trsync_trigger oid=%c reason=%c",
)
RESPONSES = (
    "stepper_position oid=%c pos=%i",
    "endstop_state oid=%c homing=%c next_clock=%u pin_value=%c",
    "trsync_state oid=%c can_trigger=%c trigger_reason=%c clock=%u",
)
FAMILY = (COMMANDS, RESPONSES)
# A timer that reschedules itself sooner than this cannot keep up on an AVR: it falls behind until
# src/avr/timer.c shuts the MCU down ("Rescheduled timer in the past"); the twin says so at once
MIN_PERIOD_S = 10e-6


@dataclass(eq=False)
class _Stepper:
    oid: int
    carriage: Carriage
    last_clock32: int = 0  # the last step's 32-bit MCU clock (reset_step_clock sets it): a move's first step is
    # 32-bit arithmetic on it, as in src/stepper.c, placed at the world clock nearest to now
    next_dir: int = 1
    need_reset: bool = False  # stopped by a trigger: moves are dropped until reset_step_clock

    def shutdown(self, clock: int) -> None:
        self.carriage.stop(clock)


@dataclass(eq=False)
class _Endstop:
    oid: int
    pin: str
    switch: Switch | Probe | None  # what presses it (None: a switch the twin never presses)
    pressed_level: int  # the pin's level when pressed (the config's ``!`` inverts it)
    homing: bool = False
    pin_value: int = 0
    first_clock: int = 0
    sample_ticks: int = 0
    sample_count: int = 0
    rest_ticks: int = 1
    next_wake: int = 0
    trsync: _Trsync | None = None
    reason: int = 0
    timer: int = 0

    def level(self, clock: int) -> int:
        pressed = self.switch is not None and self.switch.pressed(clock)
        return self.pressed_level if pressed else 1 - self.pressed_level

    def shutdown(self, clock: int) -> None:
        self.homing = False


@dataclass(eq=False)
class _Trsync:
    oid: int
    can_trigger: bool = False
    reason: int = 0
    expire_reason: int = 0
    report_ticks: int = 0
    steppers: list[_Stepper] = field(default_factory=list)
    timer: int = 0  # the report timer's version
    expire_timer: int = 0
    overdue_since: int | None = None  # lenient: the missed timeout, while waiting out the grace

    def shutdown(self, clock: int) -> None:
        self.can_trigger = False


class MotionCommands:
    """KlipperMcu's handlers for FAMILY's commands (a mixin: the oids, timers and output are the MCU's)."""

    if TYPE_CHECKING:  # what the mixin uses of KlipperMcu
        board: TwinBoard
        chip: Chip
        now: int
        strict: bool
        grace_clocks: int
        lateness: Lateness
        _oids: list[object] | None

        def _alloc(self, oid: int, obj: object) -> None: ...
        def _lookup(self, oid: int, kind: type): ...
        def _add_timer(self, clock: int, action: Callable, owner, *args) -> None: ...
        def _send(self, name: str, **values) -> None: ...
        def _output_pin(self, number: int, reason: str = ...) -> str: ...
        def _input_pin(self, number: int) -> str: ...
        def world_clock(self, clock32: int) -> int: ...
        def mcu_clock(self, clock: int) -> int: ...

    # -- src/stepper.c -------------------------------------------------------------------------------
    def _cmd_config_stepper(self, args: dict) -> None:
        pin = self._output_pin(args["step_pin"])
        self._output_pin(args["dir_pin"])
        self._alloc(args["oid"], _Stepper(args["oid"] & 0xFF, self.board.carriage(pin)))

    def _cmd_queue_step(self, args: dict) -> None:
        stepper = self._lookup(args["oid"], _Stepper)
        count = args["count"] & 0xFFFF
        if not count:
            raise Shutdown(d.INVALID_COUNT)
        if stepper.need_reset:
            return
        interval = args["interval"]
        first = self.world_clock((stepper.last_clock32 + interval) & 0xFFFFFFFF)
        move = Move(first - interval, interval, count, to_signed(args["add"], 16), stepper.next_dir)
        stepper.carriage.queue(move, self.now)
        stepper.last_clock32 = self.mcu_clock(move.step_clock(count))
        for endstop in self._endstops_on(stepper.carriage):
            self._endstop_rearm(endstop)

    def _cmd_set_next_step_dir(self, args: dict) -> None:
        self._lookup(args["oid"], _Stepper).next_dir = 1 if args["dir"] & 0xFF else -1

    def _cmd_reset_step_clock(self, args: dict) -> None:
        stepper = self._lookup(args["oid"], _Stepper)
        last = stepper.carriage.last_step_clock()
        if last is not None and last > self.now:
            raise Shutdown(d.STEPPER_ACTIVE)
        stepper.last_clock32 = args["clock"] & 0xFFFFFFFF
        stepper.need_reset = False

    def _cmd_stepper_get_position(self, args: dict) -> None:
        stepper = self._lookup(args["oid"], _Stepper)
        self._send("stepper_position", oid=stepper.oid, pos=stepper.carriage.steps_at(self.now) & 0xFFFFFFFF)

    def _cmd_stepper_stop_on_trigger(self, args: dict) -> None:
        stepper = self._lookup(args["oid"], _Stepper)
        trsync = self._lookup(args["trsync_oid"], _Trsync)
        if stepper not in trsync.steppers:  # trsync_add_signal: kept until the trsync triggers
            trsync.steppers.append(stepper)

    def _stop_stepper(self, stepper: _Stepper) -> None:
        stepper.carriage.stop(self.now)
        stepper.need_reset = True

    # -- src/endstop.c -------------------------------------------------------------------------------
    def _cmd_config_endstop(self, args: dict) -> None:
        pin = self._input_pin(args["pin"])
        switch, pressed_level = self.board.endstop(pin)
        endstop = _Endstop(args["oid"] & 0xFF, pin, switch, pressed_level)
        self._alloc(args["oid"], endstop)
        if isinstance(switch, Probe):  # a command to the probe changes it: sample again from there
            switch.on_change = lambda: self._endstop_rearm(endstop)

    def _cmd_endstop_home(self, args: dict) -> None:
        endstop = self._lookup(args["oid"], _Endstop)
        endstop.timer += 1  # sched_del_timer
        endstop.sample_count = args["sample_count"] & 0xFF
        if not endstop.sample_count:
            endstop.homing, endstop.trsync = False, None
            return
        if args["rest_ticks"] < self.chip.clocks(MIN_PERIOD_S):
            raise Shutdown(d.RESCHEDULED_IN_PAST)
        endstop.sample_ticks, endstop.rest_ticks = args["sample_ticks"], args["rest_ticks"]
        endstop.pin_value, endstop.reason = args["pin_value"] & 0xFF, args["trigger_reason"] & 0xFF
        endstop.trsync = self._lookup(args["trsync_oid"], _Trsync)
        endstop.homing = True
        endstop.first_clock = endstop.next_wake = self.world_clock(args["clock"])
        self._endstop_rearm(endstop)

    def _endstops_on(self, carriage: Carriage) -> list[_Endstop]:
        return [o for o in self._oids or ()
                if isinstance(o, _Endstop) and o.homing and o.switch is not None and o.switch.moves_with(carriage)]

    def _endstop_rearm(self, endstop: _Endstop) -> None:
        """The next sample at which the pin can match: where the queued moves press (or release) the
        switch, else after them (a new move rearms it)."""
        if not endstop.homing:
            return
        start = max(endstop.next_wake, self.now)
        if endstop.level(start) == endstop.pin_value:
            at: int | None = start
        elif endstop.switch is None or endstop.pressed_level != endstop.pin_value:
            at = None  # a switch the twin never presses (or homing on release): it never matches
        else:
            at = endstop.switch.pressed_from(start)
        if at is None:
            return
        ticks = endstop.rest_ticks
        wake = endstop.first_clock + -(-(at - endstop.first_clock) // ticks) * ticks
        self._add_timer(wake, self._endstop_sample, endstop)

    def _endstop_sample(self, endstop: _Endstop, version: int) -> None:
        """endstop_event and its oversampling: sample_count matches sample_ticks apart trigger."""
        if version != endstop.timer or not endstop.homing:
            return
        clock = self.now
        endstop.next_wake = clock + endstop.rest_ticks
        if not all(endstop.level(clock + i * endstop.sample_ticks) == endstop.pin_value
                   for i in range(endstop.sample_count)):
            self._endstop_rearm(endstop)
            return
        endstop.homing = False
        if endstop.trsync is not None:
            self.now = clock + (endstop.sample_count - 1) * endstop.sample_ticks
            self._trsync_trigger(endstop.trsync, endstop.reason)
            self.now = max(self.now, clock)

    def _cmd_endstop_query_state(self, args: dict) -> None:
        endstop = self._lookup(args["oid"], _Endstop)
        self._send("endstop_state", oid=endstop.oid, homing=int(endstop.homing),
                   next_clock=self.mcu_clock(endstop.next_wake), pin_value=endstop.level(self.now))

    # -- src/trsync.c --------------------------------------------------------------------------------
    def _cmd_config_trsync(self, args: dict) -> None:
        self._alloc(args["oid"], _Trsync(args["oid"] & 0xFF))

    def _cmd_trsync_start(self, args: dict) -> None:
        trsync = self._lookup(args["oid"], _Trsync)
        trsync.timer += 1
        trsync.expire_timer += 1
        trsync.can_trigger, trsync.reason, trsync.overdue_since = True, 0, None
        trsync.expire_reason, trsync.report_ticks = args["expire_reason"] & 0xFF, args["report_ticks"]
        if 0 < trsync.report_ticks < self.chip.clocks(MIN_PERIOD_S):
            raise Shutdown(d.RESCHEDULED_IN_PAST)
        if trsync.report_ticks:
            self._add_timer(self.world_clock(args["report_clock"]), self._trsync_report, trsync)

    def _trsync_report(self, trsync: _Trsync, version: int) -> None:
        if version != trsync.timer:
            return
        self._send_trsync_state(trsync)
        self._add_timer(self.now + trsync.report_ticks, self._trsync_report, trsync)

    def _send_trsync_state(self, trsync: _Trsync) -> None:
        self._send("trsync_state", oid=trsync.oid, can_trigger=int(trsync.can_trigger), trigger_reason=trsync.reason,
                   clock=self.mcu_clock(self.now))

    def _cmd_trsync_set_timeout(self, args: dict) -> None:
        trsync = self._lookup(args["oid"], _Trsync)
        if not trsync.can_trigger:
            return
        if trsync.overdue_since is not None:  # lenient: a renewal that came late, within the grace
            self.lateness.forgiven_deadlines += 1
            self.lateness.max_overdue_clocks = max(self.lateness.max_overdue_clocks, self.now - trsync.overdue_since)
            trsync.overdue_since = None
        trsync.expire_timer += 1
        self._add_timer(self.world_clock(args["clock"]), self._trsync_expire, None, trsync, trsync.expire_timer)

    def _trsync_expire(self, trsync: _Trsync, expire_version: int) -> None:
        """The host did not renew the timeout: the trsync triggers with its expire reason (klippy's
        "Communication timeout during homing"); in lenient mode only once the grace has passed too."""
        if expire_version != trsync.expire_timer:
            return
        if self.strict or self.grace_clocks <= 0:
            self._trsync_trigger(trsync, trsync.expire_reason)
            return
        trsync.overdue_since = self.now
        self._add_timer(self.now + self.grace_clocks, self._trsync_overdue, None, trsync, expire_version)

    def _trsync_overdue(self, trsync: _Trsync, expire_version: int) -> None:
        if expire_version == trsync.expire_timer and trsync.overdue_since is not None:
            trsync.overdue_since = None
            self._trsync_trigger(trsync, trsync.expire_reason)

    def _cmd_trsync_trigger(self, args: dict) -> None:
        trsync = self._lookup(args["oid"], _Trsync)
        self._trsync_trigger(trsync, args["reason"] & 0xFF)
        self._send_trsync_state(trsync)

    def _trsync_trigger(self, trsync: _Trsync, reason: int) -> None:
        """trsync_do_trigger: once; the linked steppers stop at this clock, and a report goes out."""
        if not trsync.can_trigger:
            return
        trsync.can_trigger, trsync.reason, trsync.overdue_since = False, reason, None
        trsync.expire_timer += 1
        trsync.timer += 1  # no more periodic reports: the one below says it triggered
        for stepper in trsync.steppers:
            self._stop_stepper(stepper)
        trsync.steppers.clear()
        self._send_trsync_state(trsync)
