"""M303 autotune: the gain arithmetic and the bias/d relay against real M303 logs, and the loop
on a small plant (transcript format, cycle count, aborts, timeout, cancel)."""

from __future__ import annotations

import re
from bisect import bisect_left
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_port.marlin.autotune import (
    STR_CLASSIC_PID,
    STR_NO_OVERSHOOT,
    Autotune,
    pid_from_relay,
    relay_gains,
    relay_levels,
    ultimate_gain,
    update_bias,
)
from firmware_port.marlin.constants import ISR_PERIOD_S, TICKS_PER_READING, ticks_to_ms
from firmware_port.marlin.protection import H_BED
from firmware_port.marlin.serial import Console, format_float
from firmware_port.thermistor import TEMP_ONE, c_to_q5

F32 = np.float32
# Repetier prints Ku from the full peak-to-peak swing, half of Marlin's Ku (it uses the same
# Classic PID rule on it); see the Kp/Ku ratio of its log line.
KU_DIVISOR = {"m303_hotend_repetier_davinci356.txt": 2}
# The Artillery bed run tunes the bed (M303 E-1), whose power field is B@.
POWER_FIELD = {"m303_bed_artillery_genius_pro_S60_configs641.txt": "B@"}
# The Prusa Buddy excerpt was abridged by its author and shows bias 245 > 235, which Marlin's
# clamp cannot produce; its header marks it lower confidence, so it is not replayed.
NOT_REPLAYED = {"m303_hotend_C2_degenerate_prusa_buddy5306.txt"}
# Consecutive bias lines of these files come from different runs: no bias step between them.
SEPARATE_RUNS = {
    "m303_hotend_single_cycle_lines_skr_marlin14486.txt",
    "m303_hotend_repetier_davinci356.txt",
}


# --- parsing the logs --------------------------------------------------------------------------


def _log_lines(path: Path) -> list[str]:
    """The captured console lines: header comments ("# ") dropped, host prefixes stripped."""
    lines = []
    for line in path.read_text().splitlines():
        if line.startswith("# "):
            continue
        lines.append(re.sub(r"^(Recv: |READ: |< [\d:]+ [AP]M: )", "", line))
    return lines


TOKEN = re.compile(
    r"(?<![\w@])(bias|d|min|max|Ku|Tu|Kp|Ki|Kd):\s*(\d+(?:\.\d+)?)|(Classic PID|No overshoot)"
)


@dataclass
class LoggedCycle:
    """One printed relay cycle: the bias line and, from cycle 3, the gains (as printed text)."""

    line: int
    values: dict[str, str] = field(default_factory=dict)
    rule: str | None = None


def _cycles(path: Path) -> list[LoggedCycle]:
    cycles: list[LoggedCycle] = []
    for number, line in enumerate(_log_lines(path), 1):
        for match in TOKEN.finditer(line):
            key, value, rule = match.groups()
            if key == "bias":
                cycles.append(LoggedCycle(number))
            if rule is not None:
                cycles[-1].rule = rule
            else:
                cycles[-1].values[key] = value
    return cycles


def _results(path: Path) -> list[LoggedCycle]:
    return [cycle for cycle in _cycles(path) if "Ku" in cycle.values]


# --- consistency of a printed result with Marlin's float32 arithmetic ------------------------


def _ku_possible(d: int, min_text: str, max_text: str, divisor: int = 1) -> tuple[float, float]:
    """The printed Ku range the true min/max allow: each is within 0.005 of what was printed."""
    lo_min, lo_max = float(min_text) - 0.005, float(max_text) + 0.005  # widest swing
    hi_min, hi_max = float(min_text) + 0.005, float(max_text) - 0.005  # narrowest swing
    lowest = ultimate_gain(d, lo_min, lo_max) / F32(divisor)
    highest = ultimate_gain(d, hi_min, hi_max) / F32(divisor)
    return float(format_float(lowest)), float(format_float(highest))


def _gains_reproducible(ku_text: str, tu_text: str, kp_text: str, ki_text: str, kd_text: str,
                        no_overshoot: bool) -> bool:
    """Some float32 Ku printing as ku_text and some whole-ms period printing as tu_text give
    exactly the printed Kp, Ki and Kd under Marlin's float32 rule."""
    ku_grid = np.linspace(float(ku_text) - 0.006, float(ku_text) + 0.006, 241, dtype=F32)
    ku_grid = np.array([k for k in ku_grid if format_float(k) == ku_text], dtype=F32)
    tu_ms = round(float(tu_text) * 1000)
    for period_ms in range(tu_ms - 10, tu_ms + 11):
        tu, kp, ki, kd = pid_from_relay(ku_grid, period_ms, no_overshoot)
        if format_float(tu) != tu_text:
            continue
        for p, i, dd in zip(kp, ki, kd):
            if (format_float(p), format_float(i), format_float(dd)) == (kp_text, ki_text, kd_text):
                return True
    return False


@pytest.mark.each_hardware_log("m303_*.txt")
def test_logged_results_are_reproduced_by_the_float32_gain_rule(hardware_log):
    path = hardware_log
    """Every logged Ku/Tu (and Kp/Ki/Kd) line is what Marlin's float32 arithmetic prints.

    The logs print min, max, Ku and Tu rounded to 2 decimals, so the exact inputs are unknown.
    What is checked honestly: (1) the printed Ku lies in the range of printed Ku that the
    float32 formula gives for min/max anywhere within +-0.005 of their printed values (Ku does
    not depend on Tu); (2) there is a float32 Ku that prints as the logged Ku and a whole-ms
    period t_low + t_high that prints as the logged Tu for which Kp, Ki and Kd print exactly as
    logged, with the rule named in the log (Classic PID, or No overshoot for Marlin 2.x beds;
    Prusa firmware prints Classic PID for its bed, Repetier uses Classic PID on half Marlin's Ku).
    """
    divisor = KU_DIVISOR.get(path.name, 1)
    for cycle in _results(path):
        v = cycle.values
        lowest, highest = _ku_possible(int(v["d"]), v["min"], v["max"], divisor)
        assert lowest <= float(v["Ku"]) <= highest, (path.name, cycle.line, lowest, highest)
        if "Kp" in v:
            assert cycle.rule in ("Classic PID", "No overshoot"), (path.name, cycle.line)
            assert _gains_reproducible(v["Ku"], v["Tu"], v["Kp"], v["Ki"], v["Kd"],
                                       cycle.rule == "No overshoot"), (path.name, cycle.line)


def test_the_logs_hold_enough_results_to_check(hardware_logs):
    results = [c for p in sorted(hardware_logs.glob("m303_*.txt")) for c in _results(p)]
    assert len(results) >= 19  # 6 + 2 + 4 + 2 + 1 + 3 + 1 Ku lines in the nine files
    assert sum("Kp" in c.values for c in results) >= 16
    assert {c.rule for c in results} >= {"Classic PID", "No overshoot"}


def test_the_documented_example_no_overshoot():
    """README section D: Ku 97.91 and Tu 36.48 give 19.58/1.07/238.13 (No overshoot)."""
    assert _gains_reproducible("97.91", "36.48", "19.58", "1.07", "238.13", no_overshoot=True)
    assert not _gains_reproducible("97.91", "36.48", "19.58", "1.07", "238.13", no_overshoot=False)


# --- the bias/d relay against the logs ---------------------------------------------------------


@pytest.mark.each_hardware_log("m303_*.txt")
def test_logged_power_levels_are_the_relay_levels_of_the_last_bias(hardware_log):
    path = hardware_log
    """Between two bias lines the tuned heater's logged power (@, or B@ for a bed) is only ever
    (bias + d) >> 1 or (bias - d) >> 1 of the last one, e.g. #8081's 127/87 after bias 214."""
    field_name = POWER_FIELD.get(path.name, "@")
    power = re.compile(r"(?<![\w@])" + re.escape(field_name) + r":(\d+)")
    levels = None
    for line in _log_lines(path):
        if "finished" in line or "Send:" in line or "failed" in line:
            levels = None  # the run is over
        bias = re.search(r"bias: (\d+) d: (\d+)", line)
        if bias:
            levels = relay_levels(int(bias[1]), int(bias[2]))
            line = line[bias.end():]
        if levels is not None:
            for amount in power.findall(line):
                assert int(amount) in levels, (path.name, line, levels)


@pytest.mark.each_hardware_log("m303_*.txt")
def test_logged_bias_steps_are_reachable_with_integer_maths(hardware_log):
    path = hardware_log
    """Every logged bias has Marlin's d, and each step to a line that prints Tu is what the
    truncating update gives for some half cycles of at least 5 s adding up to that Tu."""
    if path.name in NOT_REPLAYED:
        return
    cycles = _cycles(path)
    for cycle in cycles:
        bias, d = int(cycle.values["bias"]), int(cycle.values["d"])
        assert 20 <= bias <= 235, (path.name, cycle.line)
        assert d == (254 - bias if bias > 127 else bias), (path.name, cycle.line)
    if path.name in SEPARATE_RUNS:
        return
    for before, after in zip(cycles, cycles[1:]):
        if "Tu" not in after.values or after.line - before.line > 30:
            continue  # no period, or lines missing in between
        old_bias, old_d = int(before.values["bias"]), int(before.values["d"])
        new_bias = int(after.values["bias"])
        tu_ms = round(float(after.values["Tu"]) * 1000)
        periods = range(tu_ms - 5, tu_ms + 6)
        reachable = any(_reachable(old_bias, old_d, new_bias, p) for p in periods)
        assert reachable, (path.name, after.line)


def _reachable(old_bias: int, old_d: int, new_bias: int, period_ms: int) -> bool:
    """The new bias is monotonic in t_high for a fixed period: bisect for it."""
    highs = range(5000, period_ms - 5000 + 1)

    def bias_after(t_high_ms: int) -> int:
        return update_bias(old_bias, old_d, t_high_ms, period_ms - t_high_ms, 255)[0]
    k = bisect_left(highs, new_bias, key=bias_after)
    return k < len(highs) and bias_after(highs[k]) == new_bias


def test_bias_clamps_at_20_and_235():
    assert update_bias(30, 30, 5000, 60000, 255) == (20, 20)  # 30 - 25 -> 5 -> 20
    assert update_bias(230, 24, 60000, 5000, 255) == (235, 19)  # 230 + 20 -> 250 -> 235


def test_bias_above_half_power_swings_down_by_254_minus_bias():
    """#8081 at 250 C: bias 197 (its cooling level 70) -> 214, d 40 -> bias 206, d 48."""
    assert relay_levels(197, 57)[1] == 70
    assert update_bias(197, 57, 14300, 7700, 255) == (214, 40)  # 57 * 6600 / 22000 = 17.1
    assert update_bias(214, 40, 8700, 13270, 255) == (206, 48)  # 40 * -4570 / 21970 = -8.3
    assert update_bias(127, 127, 10000, 10000, 255) == (127, 127)
    assert update_bias(127, 127, 10080, 10000, 255) == (127, 127)  # +0.5 truncates to 0
    assert update_bias(127, 127, 10160, 10000, 255) == (128, 126)


def test_negative_corrections_truncate_toward_zero():
    # 34 * (10000 - 23000) / 33000 = -13.39: C keeps -13 (Python's // would give -14).
    assert update_bias(34, 34, 10000, 23000, 255) == (21, 21)
    assert update_bias(24, 24, 15000, 15999, 255) == (24, 24)  # -0.77 -> 0


@given(
    st.integers(20, 235),
    st.integers(5000, 1_200_000),
    st.integers(5000, 1_200_000),
    st.sampled_from([255, 200, 127]),
)
def test_update_bias_against_exact_fractions(bias, t_high_ms, t_low_ms, max_pow):
    bias = min(bias, max_pow - 20)
    d = max_pow - 1 - bias if bias > max_pow >> 1 else bias
    new_bias, new_d = update_bias(bias, d, t_high_ms, t_low_ms, max_pow)
    exact = bias + int(Fraction(d * (t_high_ms - t_low_ms), t_low_ms + t_high_ms))  # truncates
    assert new_bias == min(max(exact, 20), max_pow - 20)
    assert new_d == (max_pow - 1 - new_bias if new_bias > max_pow >> 1 else new_bias)
    on, off = relay_levels(new_bias, new_d)
    assert 0 <= off <= on <= max_pow >> 1


@given(
    st.integers(20, 127),
    st.integers(0, 300 * TEMP_ONE),
    st.integers(1, 40 * TEMP_ONE),
    st.integers(10_000, 2_400_000),
    st.booleans(),
)
def test_float32_gains_are_within_float_rounding_of_the_exact_rule(
        d, min_q5, swing_q5, period_ms, no_overshoot):
    min_c, max_c = min_q5 / TEMP_ONE, (min_q5 + swing_q5) / TEMP_ONE
    ku, tu, kp, ki, kd = relay_gains(d, min_c, max_c, period_ms, no_overshoot)
    assert all(isinstance(x, np.float32) for x in (ku, tu, kp, ki, kd))
    exact_ku = 4 * d / (np.pi * (max_c - min_c) / 2)
    tu_s = period_ms / 1000
    pf, df = (0.2, 1 / 3) if no_overshoot else (0.6, 1 / 8)
    exact_kp = pf * exact_ku
    wanted = (exact_ku, tu_s, exact_kp, 2 * exact_kp / tu_s, exact_kp * tu_s * df)
    for got, want in zip((ku, tu, kp, ki, kd), wanted):
        assert abs(float(got) - want) <= 1e-6 * abs(want)


# --- the loop on a plant -------------------------------------------------------------------------

TICK_S = float(ISR_PERIOD_S)


class TwoNodeHeater:
    """A heater block (heat capacity, power, loss to ambient) and a sensor lagging behind it."""

    def __init__(self, temp_c=25.0, *, ambient_c=25.0, heat_capacity_j_k=16.7, power_w=40.0,
                 loss_w_k=0.068, sensor_per_s=0.22):
        self.block_c = self.sensor_c = temp_c
        self.ambient_c = ambient_c
        self.heat_capacity_j_k = heat_capacity_j_k
        self.power_w = power_w
        self.loss_w_k = loss_w_k
        self.sensor_per_s = sensor_per_s

    def step(self, duty: float, dt_s: float) -> None:
        heat_w = duty * self.power_w - self.loss_w_k * (self.block_c - self.ambient_c)
        self.sensor_c += (self.block_c - self.sensor_c) * self.sensor_per_s * dt_s
        self.block_c += heat_w / self.heat_capacity_j_k * dt_s

    def reading_q5(self) -> int:
        return c_to_q5(self.sensor_c)


class FailingHeater(TwoNodeHeater):
    """The cartridge stops heating after fail_after_s (a wire breaks mid-tune)."""

    def __init__(self, fail_after_s: float):
        super().__init__()
        self.fail_after_s = fail_after_s
        self.elapsed_s = 0.0

    def step(self, duty: float, dt_s: float) -> None:
        self.elapsed_s += dt_s
        super().step(duty if self.elapsed_s < self.fail_after_s else 0.0, dt_s)


def bed_plant(temp_c=55.0):
    """A pre-warmed bed (like the Artillery log's): slow plate, slow sensor, Tu about 30 s."""
    return TwoNodeHeater(temp_c, heat_capacity_j_k=1000.0, power_w=200.0, loss_w_k=1.6,
                         sensor_per_s=0.05)


@dataclass
class Run:
    tune: Autotune
    console: Console
    start_ms: int
    end_ms: int
    report_ms: list[int]
    errors: list[tuple[int, str]]
    readings: list[tuple[int, int, bool, int]]  # ms, fresh reading, then heating and amount

    @property
    def lines(self) -> list[str]:
        return self.console.text.split("\n")


def run_m303(plant, *, target_c, ncycles, is_bed=False, version="2.1", maxtemp_c=None,
             max_ticks=1_300_000, until=None) -> Run:
    """Drive Autotune.poll every ISR tick, a fresh reading every 160 ticks, duty = amount/127."""
    console = Console()
    report_ms: list[int] = []
    errors: list[tuple[int, str]] = []
    readings: list[tuple[int, int, bool, int]] = []
    clock = {"ms": 0, "q5": plant.reading_q5()}

    def heater_states() -> str:
        report_ms.append(clock["ms"])
        temp = format_float(clock["q5"] / TEMP_ONE)
        if is_bed:
            return f" T:24.00 /0.00 B:{temp} /0.00 @:0 B@:{tune.amount}"
        return f" T:{temp} /0.00 B:24.00 /0.00 @:{tune.amount} B@:0"

    maxtemp_c = maxtemp_c or (150 if is_bed else 275)
    tune = Autotune(H_BED if is_bed else 0, target_c, ncycles, is_bed, console, heater_states,
                    lambda kind: errors.append((clock["ms"], kind)), maxtemp_c, version=version)
    start_ms = ticks_to_ms(0)
    tune.start(start_ms)
    tick = 0
    while not tune.done and tick < max_ticks and not (until and until(tune)):
        tick += 1
        plant.step(tune.amount / 127, TICK_S)
        fresh = plant.reading_q5() if tick % TICKS_PER_READING == 0 else None
        if fresh is not None:
            clock["q5"] = fresh
        clock["ms"] = ticks_to_ms(tick)
        tune.poll(clock["ms"], fresh)
        if fresh is not None:
            readings.append((clock["ms"], fresh, tune.heating, tune.amount))
    return Run(tune, console, start_ms, clock["ms"], report_ms, errors, readings)


STATUS = r" T:\d+\.\d\d /0\.00 B:24\.00 /0\.00 @:(\d+) B@:0"
BIAS = r" bias: (\d+) d: (\d+) min: (\d+\.\d\d) max: (\d+\.\d\d)"
KU = r" Ku: (\d+\.\d\d) Tu: (\d+\.\d\d)"
GAINS = r" Kp: (\d+\.\d\d) Ki: (\d+\.\d\d) Kd: (\d+\.\d\d)"
FINISHED = (
    "PID Autotune finished! Put the last Kp, Ki and Kd constants from below into Configuration.h"
)


@pytest.fixture(scope="module", params=[(40.0, 200), (22.0, 250)], ids=["200C", "250C-weak"])
def hotend_c8(request) -> Run:
    """M303 C8 on the hotend; at 250 C a 22 W heater needs bias > 127 (cooling above 0, #8081)."""
    power_w, target_c = request.param
    return run_m303(TwoNodeHeater(power_w=power_w), target_c=target_c, ncycles=8)


def test_c8_transcript_has_marlins_lines_in_marlins_order(hotend_c8):
    lines = hotend_c8.lines
    assert lines[0] == "PID Autotune start"
    assert lines[-5:] == [FINISHED, *lines[-4:-1], ""]
    assert all(re.fullmatch(r"#define DEFAULT_K[pid] \d+\.\d\d", line) for line in lines[-4:-1])
    bias_lines, ku_lines = 0, 0
    k = 1
    while lines[k] != FINISHED:
        if re.fullmatch(STATUS, lines[k]):
            k += 1
            continue
        appended = re.fullmatch(BIAS + STATUS, lines[k])  # cycles 1 and 2: the report follows
        if appended:
            bias_lines += 1
            assert bias_lines <= 2
            assert int(appended[5]) == relay_levels(int(appended[1]), int(appended[2]))[0]
            k += 1
            continue
        result = re.fullmatch(BIAS + KU, lines[k])
        assert result, lines[k]
        bias_lines += 1
        ku_lines += 1
        assert bias_lines > 2
        assert lines[k + 1] == STR_CLASSIC_PID == " Classic PID "
        assert re.fullmatch(GAINS, lines[k + 2]), lines[k + 2]
        k += 3
    assert (bias_lines, ku_lines) == (8, 6)  # cycles 1..8 print, Ku from cycle 3 (like configs641)


def test_c8_reports_every_2_s_from_the_start(hotend_c8):
    times = hotend_c8.report_ms
    assert times[0] == ticks_to_ms(1)  # due at the start time: the first poll, one tick later
    assert all(2000 <= b - a <= 2001 for a, b in zip(times, times[1:]))  # polled every 1.024 ms
    assert sum(re.fullmatch(STATUS, line) is not None or re.search(BIAS + STATUS, line) is not None
               for line in hotend_c8.lines) == len(times)


def test_c8_gains_are_the_last_printed_and_consistent_with_ku_and_tu(hotend_c8):
    tune, lines = hotend_c8.tune, hotend_c8.lines
    assert tune.done and tune.succeeded and not hotend_c8.errors
    defines = [line.split()[-1] for line in lines[-4:-1]]
    assert defines == [format_float(g) for g in tune.gains]
    k = max(k for k, line in enumerate(lines) if re.fullmatch(BIAS + KU, line))
    bias, d, min_c, max_c, ku, tu_text = re.fullmatch(BIAS + KU, lines[k]).groups()
    assert list(re.fullmatch(GAINS, lines[k + 2]).groups()) == defines
    # From Kp and the whole-ms period of the last cycle, Ki and Kd follow exactly.
    tu = pid_from_relay(F32(0.0), tune.t_high_ms + tune.t_low_ms, False)[0]
    kp = F32(tune.gains[0])
    assert format_float(tu) == tu_text
    eighth = F32(1.0) / F32(8.0)
    assert tune.gains[1:] == (float(kp * F32(2.0) / tu), float(kp * tu * eighth))
    # The printed numbers pass the same checks as the hardware logs.
    lowest, highest = _ku_possible(int(d), min_c, max_c)
    assert lowest <= float(ku) <= highest
    assert _gains_reproducible(ku, tu_text, *defines, no_overshoot=False)
    assert tune.amount == relay_levels(tune.bias, tune.d)[0]  # left on; manage_heater turns it off


def _c(temp_q5: int) -> str:
    return format_float(temp_q5 / TEMP_ONE)


def test_c8_switches_and_prints_exactly_by_marlins_rules(hotend_c8):
    """Re-derive each relay switch and each printed bias/Ku/gains line from the readings fed in.

    Off when heating, T > target and 5 s since the switch-on; on when cooling, T < target and
    5 s since the switch-off. maxT restarts at target on switching off, minT on switching on.
    """
    target_q5 = hotend_c8.tune.target_c * TEMP_ONE
    heating, on_ms, off_ms = True, hotend_c8.start_ms, hotend_c8.start_ms
    bias = d = 127
    cycles = 0
    since_on: list[int] = []  # readings after the last switch-on reading
    since_off: list[int] = []
    expected: list[str] = []
    for ms, q5, heating_after, amount in hotend_c8.readings:
        since_on.append(q5)
        since_off.append(q5)
        if heating and q5 > target_q5 and ms - on_ms >= 5000:
            heating, t_high_ms, off_ms = False, ms - on_ms, ms
            since_off = []
        elif not heating and q5 < target_q5 and ms - off_ms >= 5000:
            heating, t_low_ms = True, ms - off_ms
            if cycles > 0:
                bias, d = update_bias(bias, d, t_high_ms, t_low_ms, 255)
                min_q5, max_q5 = min(target_q5, *since_on), max(target_q5, *since_off)
                line = f" bias: {bias} d: {d} min: {_c(min_q5)} max: {_c(max_q5)}"
                if cycles > 2:
                    ku, tu, kp, ki, kd = relay_gains(d, min_q5 / TEMP_ONE, max_q5 / TEMP_ONE,
                                                     t_high_ms + t_low_ms, False)
                    line += f" Ku: {format_float(ku)} Tu: {format_float(tu)}"
                    line += f"\n{STR_CLASSIC_PID}\n Kp: {format_float(kp)} Ki: {format_float(ki)}"
                    line += f" Kd: {format_float(kd)}\n"
                expected.append(line)
            cycles += 1
            on_ms = ms
            since_on = []
        assert (heating_after, amount) == (heating, relay_levels(bias, d)[0 if heating else 1]), ms
    printed = re.findall(r" bias: .*?(?= T:)| bias: .*\n.*\n.*\n", hotend_c8.console.text)
    assert printed == expected and len(expected) == 8


def test_gains_use_marlins_float32_operation_order():
    """p * 2.0f / Tu and p * Tu * df, left to right: with df = 1/3 the order shows in the bits."""
    third = F32(1.0) / F32(3.0)
    other_order_differs = 0
    for ku in np.linspace(50, 150, 2001, dtype=F32):
        tu, kp, ki, kd = pid_from_relay(ku, 36480, no_overshoot=True)
        assert (tu, kp) == (F32(36480) * F32(0.001), ku * F32(0.2))
        assert (ki, kd) == ((kp * F32(2.0)) / tu, (kp * tu) * third)
        other_order_differs += kp * (tu * third) != kd
    assert other_order_differs > 0  # so the assertion above pins Marlin's order


def _log_defines(path: Path) -> list[str]:
    return [line.strip() for line in _log_lines(path) if line.startswith("#define")]


@pytest.mark.parametrize("ncycles", [0, 1, 2])
def test_marlin_2_1_below_c3_runs_three_cycles_and_prints_zero_gains(ncycles, hardware_logs):
    """Like the Prusa Buddy C2 log: 2 bias lines (Ku needs a 4th switch-on), then 0.00 gains."""
    run = run_m303(TwoNodeHeater(), target_c=225, ncycles=ncycles)
    assert run.tune.succeeded and run.tune.cycles == 3
    assert sum(" bias: " in line for line in run.lines) == 2
    assert not any(" Ku: " in line for line in run.lines)
    assert run.lines[-4:-1] == _log_defines(hardware_logs / "m303_hotend_C2_degenerate_prusa_buddy5306.txt")
    assert run.tune.gains == (0.0, 0.0, 0.0)


def test_marlin_1_1_with_c1_prints_the_two_space_defines_of_issue_6316(hardware_logs):
    run = run_m303(TwoNodeHeater(), target_c=222, ncycles=1, version="1.1")
    assert run.tune.succeeded and run.tune.cycles == 2
    assert run.report_ms[0] == run.start_ms + 2000  # 1.1 waits 2 s for its first report
    assert sum(" bias: " in line for line in run.lines) == 1
    assert re.search(BIAS + "(" + STATUS + r"\n)?" + re.escape(FINISHED) + "\n", run.console.text)
    assert run.lines[-4:-1] == _log_defines(hardware_logs / "m303_hotend_C1_degenerate_marlin6316.txt")
    assert run.lines[-4:-1] == ["#define  DEFAULT_Kp 0.00", "#define  DEFAULT_Ki 0.00",
                                "#define  DEFAULT_Kd 0.00"]


def test_bed_uses_no_overshoot_and_prints_bed_defines(hardware_logs):
    run = run_m303(bed_plant(), target_c=60, ncycles=3, is_bed=True)
    assert run.tune.succeeded and not run.errors
    ku_line = next(k for k, line in enumerate(run.lines) if " Ku: " in line)
    assert run.lines[ku_line + 1] == STR_NO_OVERSHOOT == " No overshoot"
    artillery = hardware_logs / "m303_bed_artillery_genius_pro_S60_configs641.txt"
    assert STR_NO_OVERSHOOT in _log_lines(artillery)
    names = [line.split()[1] for line in run.lines[-4:-1]]
    assert names == [line.split()[1] for line in _log_defines(artillery)]  # DEFAULT_bedKp ...
    values = re.fullmatch(GAINS, run.lines[ku_line + 2]).groups()
    m = re.fullmatch(BIAS + KU, run.lines[ku_line])
    assert _gains_reproducible(m[5], m[6], *values, no_overshoot=True)


def test_bed_with_marlin_1_1_uses_classic_pid():
    run = run_m303(bed_plant(), target_c=60, ncycles=3, is_bed=True, version="1.1")
    assert run.tune.succeeded
    assert STR_CLASSIC_PID in run.lines and STR_NO_OVERSHOOT not in run.lines
    assert run.lines[-4] == "#define  DEFAULT_bedKp " + format_float(run.tune.gains[0])


def test_each_half_cycle_lasts_at_least_5000_ms_elapsed_semantics():
    """ELAPSED(ms, t + 5000): a reading exactly 5000 ms after the last switch may switch."""
    tune = Autotune(0, 200, 5, False, Console(), lambda: "", _unexpected, 275)
    tune.start(1000)
    tune.poll(5999, c_to_q5(201))
    assert tune.heating and tune.amount == 127
    tune.poll(6000, c_to_q5(201))
    assert not tune.heating and tune.amount == 0 and tune.t_high_ms == 5000
    tune.poll(10_999, c_to_q5(199))
    assert not tune.heating
    tune.poll(11_000, c_to_q5(199))
    assert tune.heating and tune.t_low_ms == 5000 and tune.cycles == 1


@pytest.mark.parametrize(
    ("is_bed", "maxtemp_c", "target_c", "accepted"),
    [(False, 275, 260, True), (False, 275, 261, False), (True, 150, 140, True),
     (True, 150, 141, False)],
)
def test_target_above_maxtemp_minus_overshoot_is_refused_before_starting(
        is_bed, maxtemp_c, target_c, accepted):
    console = Console()
    heater_id = H_BED if is_bed else 0
    tune = Autotune(heater_id, target_c, 5, is_bed, console, lambda: "", _unexpected, maxtemp_c)
    tune.start(1234)
    if accepted:
        assert console.text == "PID Autotune start\n" and not tune.done and tune.amount == 127
    else:
        assert console.text == "PID Autotune failed! Temperature too high\n"
        assert tune.done and not tune.succeeded and tune.gains is None and tune.amount == 0


def test_marlin_1_1_has_no_target_check():
    console = Console()
    tune = Autotune(0, 300, 5, False, console, lambda: "", _unexpected, 275, version="1.1")
    tune.start(0)
    assert console.text == "PID Autotune start\n" and not tune.done


def _scripted(tune: Autotune, temps_c) -> None:
    """Start, then poll every tick with one reading per 160 ticks from a list of temperatures."""
    tune.start(0)
    for k, temp_c in enumerate(temps_c, 1):
        for tick in range(TICKS_PER_READING * (k - 1) + 1, TICKS_PER_READING * k + 1):
            fresh = c_to_q5(temp_c) if tick % TICKS_PER_READING == 0 else None
            tune.poll(ticks_to_ms(tick), fresh)
            if tune.done:
                return


def _unexpected(kind: str) -> None:
    raise AssertionError(f"unexpected temp_error({kind!r})")


@pytest.mark.parametrize(
    ("version", "abort_c", "amount_after"), [("2.1", 235, 0), ("1.1", 225, 127)])
def test_overshoot_aborts_above_target_plus_limit(version, abort_c, amount_after):
    """2.1: above target + 30, heaters off; 1.1: above target + 20, and it returned with the
    heater as it was (still heating here, as the 5 s minimum has not passed)."""
    console = Console()
    tune = Autotune(0, 200, 5, False, console, lambda: " T:", _unexpected, 275, version=version)
    _scripted(tune, [195, 199, 205, 215, 225, 235, 245])
    assert tune.done and not tune.succeeded and tune.gains is None
    assert console.text.endswith("\nPID Autotune failed! Temperature too high\n")
    assert tune.current_q5 == c_to_q5(abort_c)
    assert tune.amount == amount_after


def test_overshoot_limit_and_timeout_are_strict_comparisons():
    """current_temp > target + 30 aborts; (ms - min(t1, t2)) > 20 min times out."""
    console = Console()
    tune = Autotune(0, 60, 5, False, console, lambda: " T:", _unexpected, 275)
    tune.start(0)
    tune.poll(2000, c_to_q5(90))  # the report arms the watch and finds it heated
    tune.poll(6000, c_to_q5(90))  # switch off: t1 = 6000, t2 = 0
    assert not tune.done and not tune.heating
    tune.poll(1_200_000, None)
    assert not tune.done
    tune.poll(1_200_001, None)
    assert tune.done and console.text.endswith("PID Autotune failed! timeout\n")
    tune = Autotune(0, 60, 5, False, Console(), lambda: " T:", _unexpected, 275)
    tune.start(0)
    tune.poll(1000, c_to_q5(90) + 1)
    assert tune.done and tune.console.text.endswith("Temperature too high\n")


@pytest.mark.parametrize(("rise_c_per_40_s", "fails"), [(1.6, True), (2.4, False)])
def test_heating_watch_needs_2_c_per_40_s(rise_c_per_40_s, fails):
    """Each 2 s report re-arms the 40 s deadline only once T is 2 C above the last arming."""
    errors = []
    tune = Autotune(0, 200, 5, False, Console(), lambda: " T:", errors.append, 275)
    tune.start(0)
    for now_ms in range(100, 300_000, 100):
        tune.poll(now_ms, c_to_q5(100 + rise_c_per_40_s * now_ms / 40_000))
        if tune.done:
            break
    assert errors == (["Heating failed"] if fails else [])


def test_heating_failed_when_the_heater_cannot_heat():
    """Marlin's watch inside M303: no 2 C rise within WATCH_TEMP_PERIOD (40 s) of the last one."""
    run = run_m303(TwoNodeHeater(power_w=0.0), target_c=200, ncycles=5)
    (when_ms, kind), = run.errors
    assert kind == "Heating failed"
    armed_ms = run.report_ms[1]  # the report at start still saw current_temp = 0.0
    assert when_ms == min(t for t in run.report_ms if t >= armed_ms + 40_000) == run.report_ms[-1]
    assert run.tune.done and not run.tune.succeeded and run.tune.amount == 0


def test_thermal_runaway_when_the_temperature_falls_far_after_heating():
    run = run_m303(FailingHeater(fail_after_s=150.0), target_c=200, ncycles=8)
    (when_ms, kind), = run.errors
    assert kind == "Thermal Runaway" and when_ms == run.report_ms[-1]
    assert run.tune.heated and run.tune.current_q5 < (200 - 30) * TEMP_ONE
    assert run.tune.done and not run.tune.succeeded and run.tune.amount == 0


def _stuck_above_target(version: str) -> tuple[Autotune, Console, int, int]:
    """A heater that never cools below target (a hot chamber): one switch-off, then a timeout.
    Polled at each reading only, which is enough to find the first poll past the limit.
    Returns the tune, its output, and the times of the last two polls."""
    console = Console()
    tune = Autotune(0, 60, 5, False, console, lambda: " T:65.00", _unexpected, 275, version=version)
    tune.start(0)
    tick = 0
    while not tune.done:
        tick += TICKS_PER_READING
        tune.poll(ticks_to_ms(tick), c_to_q5(65))
    return tune, console, ticks_to_ms(tick - TICKS_PER_READING), ticks_to_ms(tick)


def test_timeout_20_minutes_after_the_older_switch():
    tune, console, before_ms, last_ms = _stuck_above_target("2.1")
    assert console.text.endswith(" T:65.00\nPID Autotune failed! timeout\n")
    assert tune.t2_ms == 0 and tune.t1_ms > 5000  # switched off once, never on again
    assert before_ms <= 20 * 60_000 < last_ms
    assert tune.done and not tune.succeeded and tune.amount == 0


def test_timeout_of_marlin_1_1_sums_both_switch_times():
    tune, console, before_ms, last_ms = _stuck_above_target("1.1")
    assert console.text.endswith("PID Autotune failed! timeout\n")
    assert (before_ms - tune.t1_ms) + before_ms <= 20 * 60_000 < (last_ms - tune.t1_ms) + last_ms
    assert last_ms < 11 * 60_000  # about 10 minutes, not 20


def test_cancel_ends_quietly_with_the_heater_off():
    plant = TwoNodeHeater()
    run = run_m303(plant, target_c=200, ncycles=5, until=lambda t: t.cycles >= 1)
    text = run.console.text
    run.tune.cancel()
    assert run.tune.done and not run.tune.succeeded and run.tune.amount == 0
    run.tune.poll(run.end_ms + 10_000, c_to_q5(150))
    assert run.console.text == text and run.tune.gains is None


def test_unknown_version_is_rejected():
    with pytest.raises(ValueError):
        Autotune(0, 200, 5, False, Console(), lambda: "", _unexpected, 275, version="2.0")
