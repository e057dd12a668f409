"""The twin MCU's firmware: Klipper's MCU command set as src/basecmd.c, adccmds.c, gpiocmds.c,
pwmcmds.c and sched.c run it, on a clock given from outside (no wall clock here).

Everything happens at an MCU clock: a host block at the clock it arrived (``receive``), a timer at
the clock it was scheduled for (``run_until``), so what the pins and the ADC see depends only on
the clocks, never on when the process got to run. Clocks are the world's (see board.py): the
MCU's own clock is the world clock less the clock of its last boot, sent as 32 bits.

Timing faults. A pin left on without a next value past its max_duration goes to its default
value at that clock in every mode, as src/gpiocmds.c's shutdown does. In ``strict`` mode the MCU
shuts down right there ("Missed scheduling of next digital out event"), and an event the host
scheduled in the past shuts it down too ("Timer too close", "Rescheduled timer in the past"), as
on a real MCU. In lenient mode (the default) a late event takes effect as early as the plants
allow, and an event that comes within ``grace_clocks`` after a missed max_duration is forgiven
(the pin resumes); no event by then is the same shutdown as strict mode's. Both are counted
(``Lateness``) and logged, so a loaded host computer cannot stop a run while a host that stops
updating a heater gets it switched off and the MCU shut down.

Frames that are well formed but carry bad values get what Klipper's firmware gives them: a byte
or half-word argument truncated (``uint8_t oid = args[0]``), a shutdown with its message, or
nothing (a response too long for a block is not sent).
"""

from __future__ import annotations

import heapq
import itertools
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from protocol.klipper_mcu import dictionary as d
from protocol.klipper_mcu.codec import (
    MESSAGE_DEST,
    MESSAGE_PAYLOAD_MAX,
    MESSAGE_SEQ_MASK,
    Block,
    BlockReader,
    ProtocolError,
    UnknownMessage,
    frame,
    iter_commands,
)
from protocol.klipper_mcu.dictionary import Dictionary, Shutdown
from protocol.klipper_mcu.lateness import Lateness
from protocol.klipper_mcu import motion, peripherals
from protocol.klipper_mcu.chip_temperature import chip_sensor
from protocol.klipper_mcu.motion import MotionCommands
from protocol.klipper_mcu.peripherals import PeripheralCommands

if TYPE_CHECKING:
    from protocol.klipper_mcu.board import TwinBoard

LOG = logging.getLogger(__name__)
PRINTER_FAMILIES = (motion.FAMILY, peripherals.FAMILY)  # what a printer.cfg's board serves beyond the heaters
STATS_INTERVAL_S = 5.0  # src/basecmd.c stats_update: every 5 s
STATS_TASK_CLOCKS = 100  # the nominal cost the stats report per event handled (the twin has no real one)
DEFAULT_GRACE_S = 1.0  # default wait for a late event after a missed max_duration (server: wall-based)


@dataclass(eq=False)
class _AnalogIn:
    oid: int
    pin: str
    next_begin: int = 0  # world clock of the next group's first sample
    sample_ticks: int = 0
    sample_count: int = 0
    rest_ticks: int = 0
    min_value: int = 0
    max_value: int = 0
    range_check_count: int = 0
    value: int = 0
    state: int = 0  # samples taken in the current group
    invalid_count: int = 0
    timer: int = 0  # the version of its pending timer (a newer one cancels the older)


@dataclass(eq=False)
class _DigitalOut:
    oid: int
    pin: str
    default_on: bool
    max_duration: int
    cycle_ticks: int = 0
    queue: deque = field(default_factory=deque)  # (world clock, on_ticks)
    end_time: int | None = None  # the max_duration deadline, or the next queued event's clock
    timer: int = 0
    overdue_since: int | None = None  # lenient: the missed deadline, while waiting out the grace


@dataclass(eq=False)
class _PwmOut:
    oid: int
    pin: str
    default_value: int
    max_duration: int
    queue: deque = field(default_factory=deque)  # (world clock, value)
    end_time: int | None = None
    timer: int = 0
    overdue_since: int | None = None


class KlipperMcu(MotionCommands, PeripheralCommands):
    """One MCU: the host's blocks in, response blocks out; timers on world clocks."""

    def __init__(self, board: TwinBoard, dictionary: Dictionary, *, strict: bool = False,
                 grace_clocks: int | None = None):
        """``grace_clocks``: lenient mode's wait for a late event (default DEFAULT_GRACE_S of the chip's clock)."""
        self.board, self.dictionary, self.strict = board, dictionary, strict
        self.chip = dictionary.chip
        self.grace_clocks = self.chip.clocks(DEFAULT_GRACE_S) if grace_clocks is None else grace_clocks
        self._identify = dictionary.data()
        self._by_id = dictionary.by_id
        self._output = bytearray()
        self.shutdown_reason: str | None = None  # the reason reported since the last shutdown
        self.lateness = Lateness(self.chip.clock_freq)
        self.boots = 0
        self._handlers: dict[str, Callable[[dict], None]] = {
            name: getattr(self, "_cmd_" + name, None) or self._accepted(name) for name in dictionary.commands}
        self.boot(0)

    def __repr__(self) -> str:
        return f"KlipperMcu(clock {self.now}, {'shut down: ' + str(self.shutdown_reason) if self._shutdown else 'running'})"

    # -- the outside world -------------------------------------------------------------------
    def boot(self, clock: int) -> None:
        """Power-on or reset at world clock ``clock``: all state anew, pins low, clock from 0."""
        self.boot_clock = self.now = clock
        self.boots += 1
        self._reader = BlockReader()
        self._next_sequence = MESSAGE_DEST
        self._timers: list[tuple[int, int, Callable, tuple]] = []
        self._order = itertools.count()
        self._oids: list[object] | None = None
        self._finalized = False
        self._config_crc = 0
        self._moves_used = 0
        self._shutdown = False
        self._reason_id = 0
        self._events_handled = 0
        self._output.clear()
        self.board.reset_pins(clock)
        self._add_timer(clock + self.chip.clocks(STATS_INTERVAL_S), self._stats, None)

    def receive(self, data: bytes, clock: int) -> None:
        """Bytes from the host, arriving at world clock ``clock``: timers due first, then each block."""
        self.run_until(clock)
        boots = self.boots
        for block in self._reader.feed(data):
            if block is None or MESSAGE_DEST | block.sequence != self._next_sequence:
                self._send_block(b"")  # nak: the sequence we still expect
                continue
            self._next_sequence = MESSAGE_DEST | ((block.sequence + 1) & MESSAGE_SEQ_MASK)
            self._dispatch(block)
            if boots != self.boots:
                return  # a reset: the rest of the bytes went to the board that rebooted
            self._send_block(b"")  # ack (after a shutdown the firmware's nak: the same bytes)

    def run_until(self, clock: int) -> None:
        """Run the timers due up to world clock ``clock``, each at its own clock."""
        while self._timers and self._timers[0][0] <= clock:
            at, _, action, args = heapq.heappop(self._timers)
            self.now = at
            self._events_handled += 1
            self._guarded(action, *args)
        self.now = max(self.now, clock)

    def next_timer(self) -> int | None:
        """The world clock of the next timer (the server sleeps until then)."""
        return self._timers[0][0] if self._timers else None

    def take_output(self) -> bytes:
        out = bytes(self._output)
        self._output.clear()
        return out

    @property
    def is_shutdown(self) -> bool:
        return self._shutdown

    def mcu_clock(self, clock: int) -> int:
        """The MCU's 32-bit clock at world clock ``clock``."""
        return (clock - self.boot_clock) & 0xFFFFFFFF

    def world_clock(self, clock32: int) -> int:
        """A 32-bit MCU clock from the host, as the world clock nearest to now (timer_is_before)."""
        diff = (clock32 - self.mcu_clock(self.now)) & 0xFFFFFFFF
        if diff & 0x80000000:
            diff -= 1 << 32
        return self.now + diff

    # -- blocks and messages -------------------------------------------------------------------
    def _send_block(self, payload: bytes) -> None:
        self._output += frame(self._next_sequence, payload)

    def _send(self, name: str, **values) -> None:
        """A response; one that a block cannot hold is not sent (command_encodef's need_space)."""
        payload = self.dictionary.responses[name].encode(**values)
        if len(payload) <= MESSAGE_PAYLOAD_MAX:
            self._send_block(payload)

    def _dispatch(self, block: Block) -> None:
        """Each command as it is read (src/command.c command_dispatch); a shutdown ends the block."""
        boots = self.boots
        try:
            for fmt, values in iter_commands(block, self._by_id):
                if self._shutdown and fmt.name not in d.IN_SHUTDOWN:
                    self._send("is_shutdown", static_string_id=self._reason_id)
                    continue
                self._handlers[fmt.name](values)
                if boots != self.boots:
                    return
        except UnknownMessage as error:
            LOG.warning("bad block from the host: %s", error)
            self._enter_shutdown(d.INVALID_COMMAND)
        except ProtocolError as error:
            LOG.warning("bad block from the host: %s", error)
            self._enter_shutdown(d.PARSER_ERROR)
        except Shutdown as stop:
            self._enter_shutdown(stop.reason)

    def _guarded(self, action: Callable, *args) -> None:
        try:
            action(*args)
        except Shutdown as stop:
            self._enter_shutdown(stop.reason)

    def _enter_shutdown(self, reason: str) -> None:
        """src/sched.c run_shutdown: outputs to their defaults, queues cleared, timers dropped
        (ADC sampling goes on), then "shutdown" with the first reason since the last clear."""
        if not self._shutdown:
            self._reason_id = self.dictionary.static_string_ids[reason]
            self.shutdown_reason = reason
        self._shutdown = True
        LOG.warning("MCU shutdown at clock %d: %s", self.mcu_clock(self.now), reason)
        self._timers = [t for t in self._timers if t[2] == self._stats]
        heapq.heapify(self._timers)
        for obj in self._oids or ():
            if isinstance(obj, _AnalogIn) and obj.sample_count:  # analog_in_shutdown: sampling goes on
                obj.state = 0
                obj.next_begin += obj.rest_ticks
                self._add_timer(obj.next_begin, self._analog_event, obj)
            elif isinstance(obj, _DigitalOut | _PwmOut):
                obj.queue.clear()
                obj.end_time = obj.overdue_since = None
                self._to_default(obj)
            elif hasattr(obj, "shutdown"):  # motion.py's: steppers stop, homing ends
                obj.shutdown(self.now)
        self._moves_used = 0
        self._send("shutdown", clock=self.mcu_clock(self.now), static_string_id=self._reason_id)

    # -- timers ----------------------------------------------------------------------------------
    def _add_timer(self, clock: int, action: Callable, owner, *args) -> None:
        """Schedule ``action(owner, version, *args)`` (owner None: ``action(*args)``); a newer timer
        of the same owner makes this one a no-op."""
        if owner is None:
            heapq.heappush(self._timers, (clock, next(self._order), action, args))
            return
        owner.timer += 1
        heapq.heappush(self._timers, (clock, next(self._order), action, (owner, owner.timer, *args)))

    def _schedule(self, clock: int, action: Callable, owner, *, rescheduled: bool = False) -> None:
        """sched_add_timer: a clock already past is "Timer too close" (a timer rescheduling itself:
        "Rescheduled timer in the past") in strict mode, and a late event otherwise."""
        if clock < self.now:
            if self.strict:
                raise Shutdown(d.RESCHEDULED_IN_PAST if rescheduled else d.TIMER_TOO_CLOSE)
            self.lateness.late_events += 1
            self.lateness.max_late_clocks = max(self.lateness.max_late_clocks, self.now - clock)
        self._add_timer(clock, action, owner)

    def _to_default(self, out: _DigitalOut | _PwmOut) -> None:
        if isinstance(out, _DigitalOut):
            self.board.drive(out.pin, self.now, int(out.default_on), 1)
        else:
            self.board.drive(out.pin, self.now, out.default_value, self.chip.pwm_max)

    def _deadline_missed(self, out: _DigitalOut | _PwmOut, reason: str) -> None:
        """max_duration passed with no next value: the pin to its default at once; in strict mode
        (or with no grace) Klipper's shutdown, in lenient mode that shutdown after the grace unless
        an event comes first (``_forgive``)."""
        out.end_time = None
        if self.strict or self.grace_clocks <= 0:
            raise Shutdown(reason)
        self._to_default(out)
        out.overdue_since = self.now
        LOG.warning("lenient MCU: %s at clock %d: %s at its default, shutdown unless an event comes within %.0f ms",
                    reason, self.mcu_clock(self.now), out.pin, self.grace_clocks * 1000 / self.chip.clock_freq)
        self._add_timer(self.now + self.grace_clocks, self._overdue, out, reason)

    def _overdue(self, out: _DigitalOut | _PwmOut, version: int, reason: str) -> None:
        if version == out.timer:
            raise Shutdown(reason)

    def _forgive(self, out: _DigitalOut | _PwmOut) -> None:
        """A late event for a pin waiting out its grace: counted, and the pin runs on."""
        if out.overdue_since is None:
            return
        overdue = self.now - out.overdue_since
        out.overdue_since = None
        self.lateness.forgiven_deadlines += 1
        self.lateness.max_overdue_clocks = max(self.lateness.max_overdue_clocks, overdue)
        LOG.warning("lenient MCU: %s's next event came %.1f ms after its max_duration (forgiven)",
                    out.pin, overdue * 1000 / self.chip.clock_freq)

    def _stats(self) -> None:
        count = self._events_handled
        task = STATS_TASK_CLOCKS
        self._send("stats", count=count, sum=count * task, sumsq=count * -(-task * task // d.STATS_SUMSQ_BASE))
        self._events_handled = 0
        self._add_timer(self.now + self.chip.clocks(STATS_INTERVAL_S), self._stats, None)
        if self.lateness.changed():
            LOG.warning(self.lateness.line())

    # -- oids and moves ----------------------------------------------------------------------------
    def _alloc(self, oid: int, obj: object) -> None:
        oid &= 0xFF  # uint8_t oid
        if self._oids is None or oid >= len(self._oids) or self._oids[oid] is not None or self._finalized:
            raise Shutdown(d.CANT_ASSIGN_OID)
        self._oids[oid] = obj

    def _lookup(self, oid: int, kind: type):
        oid &= 0xFF
        obj = self._oids[oid] if self._oids is not None and oid < len(self._oids) else None
        if not isinstance(obj, kind):
            raise Shutdown(d.INVALID_OID)
        return obj

    def _move_alloc(self) -> None:
        if not self._finalized or self._moves_used >= d.MOVE_COUNT:  # no free list before finalize_config
            raise Shutdown(d.MOVE_QUEUE_OVERFLOW)
        self._moves_used += 1

    # -- src/basecmd.c, src/command.c, src/sched.c -----------------------------------------------
    def _cmd_identify(self, args: dict) -> None:
        offset = args["offset"]
        self._send("identify_response", offset=offset, data=self._identify[offset:offset + (args["count"] & 0xFF)])

    def _cmd_get_uptime(self, args: dict) -> None:
        uptime = self.now - self.boot_clock
        self._send("uptime", high=uptime >> 32, clock=uptime & 0xFFFFFFFF)

    def _cmd_get_clock(self, args: dict) -> None:
        self._send("clock", clock=self.mcu_clock(self.now))

    def _cmd_get_config(self, args: dict) -> None:
        self._send("config", is_config=int(self._finalized), crc=self._config_crc, is_shutdown=int(self._shutdown),
                   move_count=d.MOVE_COUNT if self._finalized else 0)

    def _cmd_allocate_oids(self, args: dict) -> None:
        if self._oids is not None:
            raise Shutdown(d.OIDS_ALLOCATED)
        self._oids = [None] * (args["count"] & 0xFF)

    def _cmd_finalize_config(self, args: dict) -> None:
        if self._finalized:
            raise Shutdown(d.ALREADY_FINALIZED)
        self._finalized = True
        self._config_crc = args["crc"]

    def _cmd_emergency_stop(self, args: dict) -> None:
        raise Shutdown(d.COMMAND_REQUEST)

    def _cmd_clear_shutdown(self, args: dict) -> None:
        if not self._shutdown:
            raise Shutdown(d.CLEARED_WHEN_NOT_SHUTDOWN)
        self._shutdown = False

    def _cmd_reset(self, args: dict) -> None:
        """The board reboots: the host sees its port go quiet and reconnects to a new boot."""
        self.boot(self.now)

    def _cmd_config_reset(self, args: dict) -> None:
        if not self._shutdown:
            raise Shutdown(d.CONFIG_RESET_NOT_SHUTDOWN)
        self._oids, self._finalized, self._config_crc, self._moves_used = None, False, 0, 0
        self._timers = [t for t in self._timers if t[2] == self._stats]
        heapq.heapify(self._timers)
        self._shutdown = False

    def _cmd_debug_nop(self, args: dict) -> None:
        pass

    def _cmd_debug_read(self, args: dict) -> None:
        """src/basecmd.c: a word of memory; the twin has only an STM32's temperature calibration (else 0)."""
        sensor = chip_sensor(self.chip.mcu_constant)
        self._send("debug_result", val=0 if sensor is None else sensor.read(args["addr"]))

    # -- src/adccmds.c ---------------------------------------------------------------------------------
    def _cmd_config_analog_in(self, args: dict) -> None:
        chip = self.dictionary.chip
        pin = chip.pin_name(args["pin"] & 0xFF)  # gpio_adc_setup(uint8_t pin)
        if pin not in chip.adc_pins:
            raise Shutdown(d.NOT_ADC_PIN)
        self._alloc(args["oid"], _AnalogIn(args["oid"] & 0xFF, pin))

    def _cmd_query_analog_in(self, args: dict) -> None:
        a = self._lookup(args["oid"], _AnalogIn)
        a.timer += 1  # sched_del_timer
        a.next_begin = self.world_clock(args["clock"])
        a.sample_ticks, a.sample_count, a.rest_ticks = args["sample_ticks"], args["sample_count"] & 0xFF, args["rest_ticks"]
        a.min_value, a.max_value = args["min_value"] & 0xFFFF, args["max_value"] & 0xFFFF
        a.range_check_count = args["range_check_count"] & 0xFF
        a.state = a.value = 0
        if a.sample_count:
            self._schedule(a.next_begin, self._analog_event, a)

    def _analog_event(self, a: _AnalogIn, version: int) -> None:
        """One conversion; after the group's last, the range check and the report (the sum)."""
        if version != a.timer:
            return
        sample = self.board.adc(a.pin, self.now)
        a.value = (sample if a.state == 0 else a.value + sample) & 0xFFFF  # uint16_t value
        a.state += 1
        if a.state < a.sample_count:
            self._add_timer(self.now + a.sample_ticks, self._analog_event, a)
            return
        a.state = 0
        if a.min_value <= a.value <= a.max_value:
            a.invalid_count = 0
        else:
            a.invalid_count += 1
            if a.invalid_count >= a.range_check_count and not self._shutdown:  # try_shutdown: no report
                a.invalid_count = 0
                raise Shutdown(d.ADC_OUT_OF_RANGE)
        a.next_begin += a.rest_ticks
        if a.next_begin <= self.now:  # a real MCU falls further behind each group until it gives up
            if self._shutdown:
                return  # (it would spin on, sampling: the twin stops instead)
            raise Shutdown(d.RESCHEDULED_IN_PAST)
        self._add_timer(a.next_begin, self._analog_event, a)
        self._send("analog_in_state", oid=a.oid, next_clock=self.mcu_clock(a.next_begin), value=a.value)

    def _output_pin(self, number: int, reason: str = d.NOT_OUTPUT_PIN) -> str:
        """gpio_out_setup(uint8_t pin) (gpio_pwm_setup: ``reason`` "Not a valid PWM pin"): the pin's
        name, or that shutdown for a number that is not one of the chip's (src/avr/gpio.c, hard_pwm.c)."""
        number &= 0xFF
        chip = self.dictionary.chip
        if not chip.has_pin(number):
            raise Shutdown(reason)
        return chip.pin_name(number)

    def _input_pin(self, number: int) -> str:
        """gpio_in_setup(uint8_t pin): the pin's name, or "Not a valid input pin"."""
        number &= 0xFF
        if not self.dictionary.chip.has_pin(number):
            raise Shutdown(d.NOT_INPUT_PIN)
        return self.dictionary.chip.pin_name(number)

    # -- src/gpiocmds.c -------------------------------------------------------------------------------
    def _cmd_config_digital_out(self, args: dict) -> None:
        pin = self._output_pin(args["pin"])
        self._alloc(args["oid"], _DigitalOut(args["oid"], pin, bool(args["default_value"]), args["max_duration"]))
        self.board.drive(pin, self.now, int(bool(args["value"])), 1)

    def _cmd_set_digital_out_pwm_cycle(self, args: dict) -> None:
        out = self._lookup(args["oid"], _DigitalOut)
        if out.queue:
            raise Shutdown(d.CYCLE_WHILE_PENDING)
        out.cycle_ticks = args["cycle_ticks"]

    def _queue(self, out: _DigitalOut | _PwmOut, clock32: int, value: int, exceeds: str, load: Callable) -> None:
        """Queue a value for a clock; the first in an empty queue is scheduled (a pending max_duration
        deadline before it: ``exceeds``), the others load as the one before them ends."""
        self._move_alloc()
        clock = self.world_clock(clock32)
        out.queue.append((clock, value))
        if len(out.queue) > 1:
            return
        self._forgive(out)
        if out.end_time is not None and out.end_time < clock:
            raise Shutdown(exceeds)
        out.end_time = clock if isinstance(out, _DigitalOut) else None
        self._schedule(clock, load, out)

    def _cmd_queue_digital_out(self, args: dict) -> None:
        out = self._lookup(args["oid"], _DigitalOut)
        self._queue(out, args["clock"], args["on_ticks"], d.DIGITAL_OUT_EXCEEDS, self._digital_load)

    def _digital_load(self, out: _DigitalOut, version: int) -> None:
        """digital_load_event: apply the next queued value, set the next deadline."""
        if version != out.timer:
            return
        if not out.queue:
            self._deadline_missed(out, d.MISSED_DIGITAL_OUT)
            return
        _, on_ticks = out.queue.popleft()
        self._moves_used -= 1
        cycle = out.cycle_ticks
        if cycle and 0 < on_ticks < cycle:
            self.board.drive(out.pin, self.now, on_ticks, cycle)
        else:
            self.board.drive(out.pin, self.now, int(on_ticks > 0), 1)
        steady_default = (on_ticks == 0 or on_ticks >= cycle) and bool(on_ticks) == out.default_on
        end_time = None if steady_default or not out.max_duration else self.now + out.max_duration
        if out.queue:
            wake = out.queue[0][0]
            if end_time is not None and end_time < wake:
                raise Shutdown(d.DIGITAL_OUT_EXCEEDS)
            end_time = wake
        out.end_time = end_time
        if end_time is not None:
            self._schedule(end_time, self._digital_load, out, rescheduled=True)

    def _cmd_update_digital_out(self, args: dict) -> None:
        out = self._lookup(args["oid"], _DigitalOut)
        out.timer += 1
        if out.queue:
            raise Shutdown(d.UPDATE_WITH_QUEUE)
        self._forgive(out)
        value = bool(args["value"] & 0xFF)
        self.board.drive(out.pin, self.now, int(value), 1)
        out.end_time = None
        if value != out.default_on and out.max_duration:
            out.end_time = self.now + out.max_duration
            self._add_timer(out.end_time, self._digital_load, out)

    def _cmd_set_digital_out(self, args: dict) -> None:
        self.board.drive(self._output_pin(args["pin"]), self.now, int(bool(args["value"] & 0xFF)), 1)

    # -- src/pwmcmds.c ----------------------------------------------------------------------------------
    def _cmd_config_pwm_out(self, args: dict) -> None:
        pin = self._output_pin(args["pin"], d.NOT_PWM_PIN)
        self._alloc(args["oid"], _PwmOut(args["oid"] & 0xFF, pin, args["default_value"] & 0xFFFF, args["max_duration"]))
        self.board.drive(pin, self.now, args["value"] & 0xFFFF, self.chip.pwm_max)

    def _cmd_queue_pwm_out(self, args: dict) -> None:
        out = self._lookup(args["oid"], _PwmOut)
        self._queue(out, args["clock"], args["value"] & 0xFFFF, d.PWM_EXCEEDS, self._pwm_event)

    def _pwm_event(self, out: _PwmOut, version: int) -> None:
        if version != out.timer:
            return
        if not out.queue:  # pwm_end_event
            self._deadline_missed(out, d.MISSED_PWM)
            return
        _, value = out.queue.popleft()
        self._moves_used -= 1
        self.board.drive(out.pin, self.now, value, self.chip.pwm_max)
        limited = value != out.default_value and out.max_duration
        out.end_time = None
        if out.queue:
            wake = out.queue[0][0]
            if limited and self.now + out.max_duration < wake:
                raise Shutdown(d.PWM_EXCEEDS)
            self._schedule(wake, self._pwm_event, out, rescheduled=True)
        elif limited:
            out.end_time = self.now + out.max_duration
            self._add_timer(out.end_time, self._pwm_event, out)

    def _cmd_set_pwm_out(self, args: dict) -> None:
        self.board.drive(self._output_pin(args["pin"], d.NOT_PWM_PIN), self.now, args["value"] & 0xFFFF, self.chip.pwm_max)

