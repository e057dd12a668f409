"""Batch twins: N hotend twins advanced together as numpy lanes (N candidate gain sets).

Every lane has the same plant model, scenario and clock and its own PID gains; the firmware
runs vectorised (``firmware_port.marlin.lanes``) and the plant's exact per-tick maps act on all
lanes at once, so one control period of N twins costs a few matrix products. A tuner evaluates
a whole population in one run; tests/test_lanes.py keeps each lane equal to a scalar ``Twin``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from firmware_port.controller import Tunable
from firmware_port.marlin.lanes import HotendLanes
from firmware_port.marlin.pid import PREV_TEMP_EVERY_SAMPLE, PidFixed, PidGains
from firmware_port.thermistor import TEMP_ONE
from twin.clock import TICK_S, EventQueue, ticks_at
from twin.linear import BLOCK, SENSOR
from twin.result import RunResult
from twin.sensor import SensorChain


def lane_gains(controllers: Sequence[PidGains | Tunable], prev_temp_mode: str) -> list[PidGains]:
    """Each lane's gains: given directly, or taken from an injected fixed-point PID controller
    (the lanes vectorise exactly that law, so its derivative mode must match the batch's)."""
    gains = []
    for lane, item in enumerate(controllers):
        if isinstance(item, PidGains):
            gains.append(item)
        elif isinstance(item, PidFixed) and item.prev_temp_mode == prev_temp_mode:
            gains.append(item.gains)
        else:
            raise TypeError(f"lane {lane}: a batch runs PidGains or PidFixed controllers with prev_temp_mode "
                            f"{prev_temp_mode!r}, not {item!r}")
    return gains


class BatchTwin:
    """N hotends on one plant model; ``run_until`` then read ``t_s``, ``measured_c``, ``duty`` ...

    Records one row per firmware reading: arrays of shape (rows, N) for the firmware's measured
    temperature, the true block and sensor temperatures and the duty (amount / 127).
    """

    def __init__(self, plant, gains: Sequence[PidGains | Tunable], *, prev_temp_mode: str = PREV_TEMP_EVERY_SAMPLE,
                 sensor: SensorChain | None = None):
        if not plant.linear or plant.delay_ticks:
            raise ValueError("batch twins need a linear plant without dead time")
        self.plant = plant  # the template: model, conditions, disturbances
        self.n_lanes = len(gains)
        self.x = np.repeat(plant.x[:, None], self.n_lanes, axis=1)  # (n_x, N)
        self.sensor = sensor if sensor is not None else SensorChain()
        self.lanes = HotendLanes(lane_gains(gains, prev_temp_mode), prev_temp_mode)
        self.tick = 0
        self._events = EventQueue()
        self._rows: list[tuple] = []
        self._targets: list[int] = []  # the target in force at each row

    def schedule(self, at_s: float, action: Callable[[BatchTwin], None]) -> None:
        """Run ``action(batch)`` at the first tick at or after ``at_s``."""
        self._events.push(ticks_at(at_s), action, self)

    def set_target(self, target_c: int) -> None:
        self.lanes.set_target(target_c)

    def run(self, seconds: float) -> RunResult:
        """Run ``seconds`` more; the result of every lane since time 0 (arrays (rows, lanes))."""
        self.run_until(self.tick * TICK_S + seconds)
        return self.result()

    def result(self, label: str = "batch") -> RunResult:
        n = len(self._rows)
        target = np.repeat(np.array(self._targets, dtype=float)[:, None], self.n_lanes, axis=1).reshape(n, -1)
        hotend = {"target_c": target, "measured_c": self.measured_c, "block_c": self.block_c,
                  "sensor_c": self.sensor_c, "duty": self.duty}
        return RunResult.from_columns(self.t_s, {"hotend": hotend}, label=f"{label}, {self.n_lanes} lanes")

    def run_until(self, t_s: float) -> None:
        end = ticks_at(t_s)
        while self.tick < end:
            for _, action, args in self._events.pop_due(self.tick):
                action(*args)
            due = self._events.next_at()
            stop = end if due is None else min(end, due)
            if stop > self.tick:
                self._period(min(stop - self.tick, self.lanes.adc.ticks_to_reading()))

    def _period(self, n: int) -> None:
        """As ``Twin._fast_period``, on all lanes: PWM pulses summed through the step table."""
        lanes, model, d = self.lanes, self.plant.model, self.plant.d
        offsets = tuple(lanes.adc.sample_offsets(n)[0])
        px, _, pd, fx, _, fd = model.run_maps(n, offsets)
        steps = model.u_steps(n)  # (n + 1, n_x)
        pulses = lanes.pulses(n)
        samples = np.zeros((0, self.n_lanes), np.int64)
        if offsets:
            s = np.array(offsets)[:, None]
            sensor_steps = steps @ model.lti.c[SENSOR]
            sensor_c = px[:, SENSOR] @ self.x + (pd[:, SENSOR] @ d)[:, None]
            for alpha, beta in pulses:
                sensor_c += sensor_steps[np.maximum(s - alpha, 0)] - sensor_steps[np.maximum(s - beta, 0)]
            samples = self.sensor.convert(sensor_c, self.tick + s)
        lanes.skip(n, samples)
        pins_before = lanes.pins.copy()
        reading = lanes.adc.raw_ready
        lanes.task()
        x = fx @ self.x + (fd @ d)[:, None]
        for alpha, beta in pulses:
            x += (steps[n - alpha] - steps[n - beta]).T
        # the main loop may have written the pin for the last tick
        self.x = x + np.outer(model.g, lanes.pins.astype(float) - pins_before)
        self.tick += n
        if reading:
            temps = model.lti.c @ self.x + (model.lti.f @ d)[:, None]
            self._rows.append((self.tick * TICK_S, lanes.temp_q5 / TEMP_ONE, temps[BLOCK], temps[SENSOR],
                               lanes.amount / 127))
            self._targets.append(lanes.target_c)

    def _column(self, index: int) -> np.ndarray:
        return np.array([row[index] for row in self._rows])

    @property
    def t_s(self) -> np.ndarray:
        return self._column(0)

    @property
    def measured_c(self) -> np.ndarray:
        return self._column(1)

    @property
    def block_c(self) -> np.ndarray:
        return self._column(2)

    @property
    def sensor_c(self) -> np.ndarray:
        return self._column(3)

    @property
    def duty(self) -> np.ndarray:
        return self._column(4)
