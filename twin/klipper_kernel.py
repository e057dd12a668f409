"""The Klipper loop's lanes as one compiled loop per lane (numba): ``KlipperBatch``'s kernel.

Each lane is a ``KlipperTwin`` with one heater (twin/klipper_twin.py): the MCU's ADC sums 8
conversions every 0.3 s, Klipper's host runs ``ControlPID`` and ``set_pwm`` on each report (Python
float there, IEEE double here: the same operations in the same order), the PWM it sends drives the
MCU's soft PWM 0.3 s later, ``verify_heater`` checks once a second, and the MCU's ADC range check and
a verify fault shut the lane down. The shared clock is a plan of operations in KlipperTwin's event
order (time, then its priorities): ADC windows, reports, verify checks, and plant advances where a
scenario event falls.

The plant steps on its 1.024 ms tick as the scalar twin's does, from one ADC window to the next in
one run: the soft PWM's on-intervals (fractional ticks: the cycle is 0.1 s, not a whole number of
ticks) enter through the plant's step-response tables, a partial tick weighted by its on-fraction,
which is what ``SoftPwm.tick_duties`` feeds the scalar plant (to float rounding). Dead time: the
plant sees the pin's waveform ``delay`` ticks late (the lane keeps its past PWM segments); a
radiating plant is relinearised at each run's start, as ``_Channel.advance_plant`` does.

The ADC counts come from a table of switching temperatures of Klipper's converter
(``floor(4096 R / (R + Rp))`` of the thermistor's Steinhart-Hart model), the host's
temperature from a table of ``calc_temp`` over every sum: the host sees the very numbers the scalar
twin computes, as long as the plant's temperature, equal to float rounding, does not straddle a
switching temperature. A noisy lane's conversion is ``floor(analog + noise)``, clipped, as
``KlipperTwin._adc_sample`` computes it: the analog value from ``calc_adc`` itself (libm's ``exp`` and
``cbrt``, which may differ from numpy's in the last bit: with the plant's rounding, about 1e-10 LSB),
the noise drawn outside (``KlipperBatch``: one stream per seed). A count differs from the scalar
twin's only if the noisy value falls that near an integer. tests/twin/test_klipper_batch.py compares
them lane by lane.
"""

from __future__ import annotations

import numpy as np

from twin.batch_kernel import adc_count, inline, jit, output, score_row

# Operations of the plan, column OP; columns: OP, TICK, RUN_KIND, WINDOW_KIND, ROW (a report's row, an ADC
# window's first noise draw), FLAGS (int64) and TIME, LAST_S (float64, ``plan_t``).
ADC, REPORT, VERIFY, ADVANCE = range(4)
OP, TICK, RUN_KIND, WINDOW_KIND, ROW, FLAGS = range(6)
PLAN_COLUMNS = 6
TIME, LAST_S = range(2)
# Per-lane floats, ``fstate`` (N, N_F).
(LAST_TEMP, SMOOTHED, LAST_TEMP_TIME, LAST_PWM, NEXT_PWM_TIME, PREV_TEMP, PREV_TEMP_TIME, PREV_DERIV,
 PREV_INTEG, V_LAST_TARGET, V_GOAL_TEMP, V_GOAL_TIME, V_ERROR, SHUTDOWN_AT, READ_SENSOR, READ_BLOCK,
 REC_TEMP, REC_DUTY) = range(18)
N_F = 18
# Per-lane integers, ``kstate`` (N, N_K).
HALTED, INVALID, HINT, V_APPROACHING, V_STARTING, SEG_HEAD, SEG_LEN, PLANT_TICK, ADC_VALUE, TRIP = range(10)
N_K = 10
NO_TRIP, RANGE_TRIP, VERIFY_TRIP = range(3)
# Per-lane gains, ``gains`` (N, 4): Kp, Ki, Kd per unit duty (the config's / 255) and the integral's clamp.
G_KP, G_KI, G_KD, G_INTEG_MAX = range(4)
# Shared settings, ``cfg``.
(C_TARGET, C_MAX_POWER, C_INV_SMOOTH, C_SMOOTH, C_PWM_DELAY, C_MIN_PWM_CHANGE, C_MAX_HEAT, C_RESEND_2025_08,
 C_CYCLE_S, C_CYCLE_TICKS, C_CLOCK_HZ, C_MIN_SUM, C_MAX_SUM, C_RANGE_COUNT, C_V_HYST, C_V_MAX_ERROR, C_V_GAIN,
 C_V_GAIN_TIME, C_STALE_S, C_TICK_S, C_DELAY, C_ADC_MAX, C_BIN_LO, C_RADIATING, C_RECORD, C_SCORE,
 C_ROW_BASE, C_LOST_REPORTS) = range(28)
N_CFG = 28
# ``sensor_p``: the thermistor's Steinhart-Hart model and the converter, for a noisy sample's analog value.
SP_C1, SP_C2, SP_C3, SP_P27, SP_KELVIN, SP_PULLUP, SP_SCALE = range(7)
N_SP = 7
MAX_INTERVALS = 64  # on-intervals in one run: 0.3 s of 0.1 s cycles, a few PWM values, fragments (ample)


@inline
def _advance_segments(ks, seg, lo_s):
    """Forget PWM segments that ended by ``lo_s`` (pin time): the plant will never see them again."""
    cap = seg.shape[0]
    while ks[SEG_LEN] > 1 and seg[(ks[SEG_HEAD] + 1) % cap, 0] <= lo_s:
        ks[SEG_HEAD] = (ks[SEG_HEAD] + 1) % cap
        ks[SEG_LEN] -= 1


@inline
def _intervals(ks, seg, cfg, lo_s, hi_s, out):
    """The pin's on-intervals over [lo_s, hi_s) (seconds), relative to lo_s in ticks, into ``out``
    (MAX_INTERVALS, 2); returns how many. Each PWM value restarts the cycle: on for ``on_s`` from its
    time and every cycle after, until the next value."""
    cap, cycle, tick_s = seg.shape[0], cfg[C_CYCLE_S], cfg[C_TICK_S]
    k = 0
    for i in range(ks[SEG_LEN]):
        slot = (ks[SEG_HEAD] + i) % cap
        t0, on = seg[slot, 0], seg[slot, 1]
        end = seg[(slot + 1) % cap, 0] if i + 1 < ks[SEG_LEN] else np.inf
        if t0 >= hi_s:
            break
        start, stop = max(lo_s, t0), min(hi_s, end)
        if on <= 0.0 or start >= stop:
            continue
        cycles = np.floor((start - t0) / cycle)
        while True:
            c0 = t0 + cycles * cycle
            if c0 >= stop:
                break
            a, b = max(c0, start), min(c0 + on, stop)
            if b > a and k < out.shape[0]:
                out[k, 0], out[k, 1] = (a - lo_s) / tick_s, (b - lo_s) / tick_s
                k += 1
            cycles += 1.0
    return k


@inline
def _pulse_state(xn, steps, n, a, b):
    """Add to xn the state n ticks after x = 0 under an input on over fractional ticks [a, b)."""
    ia, ib = int(np.floor(a)), int(np.floor(b))
    for i in range(xn.shape[0]):
        if ia == ib:
            v = (b - a) * (steps[n - ia, i] - steps[n - ia - 1, i])
        else:
            v = (ia + 1 - a) * (steps[n - ia, i] - steps[n - ia - 1, i]) + (steps[n - ia - 1, i] - steps[n - ib, i])
            if ib < n:
                v = v + (b - ib) * (steps[n - ib, i] - steps[n - ib - 1, i])
        xn[i] = xn[i] + v


@inline
def _pulse_output(row_steps, s, a, b):
    """An output s ticks after x = 0 under an input on over fractional ticks [a, b) cut to [0, s)."""
    b = min(b, float(s))
    if b <= a:
        return 0.0
    ia, ib = int(np.floor(a)), int(np.floor(b))
    if ia == ib:
        return (b - a) * (row_steps[s - ia] - row_steps[s - ia - 1])
    v = (ia + 1 - a) * (row_steps[s - ia] - row_steps[s - ia - 1]) + (row_steps[s - ia - 1] - row_steps[s - ib])
    if ib < s:
        v = v + (b - ib) * (row_steps[s - ib] - row_steps[s - ib - 1])
    return v


@inline
def _advance(ks, seg, cfg, xl, xn, fx, fdd, steps, m, kind, tick, iv):
    """Run the plant from the lane's tick to ``tick`` in one run (model m): free response plus the
    pin's on-intervals, ``C_DELAY`` ticks late."""
    n = tick - ks[PLANT_TICK]
    if n <= 0:
        return
    delay, tick_s = int(cfg[C_DELAY]), cfg[C_TICK_S]
    lo_s = (ks[PLANT_TICK] - delay) * tick_s
    _advance_segments(ks, seg, lo_s)
    n_iv = _intervals(ks, seg, cfg, lo_s, (tick - delay) * tick_s, iv)
    for i in range(xl.shape[0]):
        v = fx[m, kind, i, 0] * xl[0]
        for k in range(1, xl.shape[0]):
            v = v + fx[m, kind, i, k] * xl[k]
        xn[i] = v + fdd[m, kind, i]
    for p in range(n_iv):
        _pulse_state(xn, steps[m], n, iv[p, 0], iv[p, 1])
    for i in range(xl.shape[0]):
        xl[i] = xn[i]
    ks[PLANT_TICK] = tick


@inline
def _window_output(xl, maps, dd, row_steps, m, window, j, offset, n_iv, iv):
    """An output (sensor or block: its maps and step responses) at a window's offset j."""
    y = maps[m, window, 0, j] * xl[0]
    for i in range(1, xl.shape[0]):
        y = y + maps[m, window, i, j] * xl[i]
    y = y + dd[m, window, j]
    for p in range(n_iv):
        y = y + _pulse_output(row_steps[m], offset, iv[p, 0], iv[p, 1])
    return y


@inline
def _analog(y, sp):
    """Klipper's calc_adc of temperature y times the converter's scale: ``SteinhartHart.resistance_ohm``
    (closed form for beta, Cardano otherwise) and the divider, in their order of operations."""
    inv_t = 1.0 / (y + sp[SP_KELVIN])
    if sp[SP_C3] == 0.0:
        r = np.exp((inv_t - sp[SP_C1]) / sp[SP_C2])
    else:
        q = (sp[SP_C1] - inv_t) / sp[SP_C3]
        disc = np.sqrt(q * q / 4.0 + sp[SP_P27])
        r = np.exp(np.cbrt(-q / 2.0 + disc) + np.cbrt(-q / 2.0 - disc))
    return r / (sp[SP_PULLUP] + r) * sp[SP_SCALE]


@inline
def _adc(ks, fs, seg, cfg, xl, px, pdd, bx, bdd, sensor_steps, block_steps, m, window, offsets, n_off, edges, iv,
         noise_lsb, z, z0, sp):
    """The MCU's summed reading of the window at the lane's tick: 8 samples (the last offset is the
    report's read time: the true temperatures recorded there), then the range check. A noisy lane's
    conversion j is ``floor(analog + noise_lsb * z[z0 + j])`` clipped to the converter's range; a
    noiseless one's count comes from the switching temperatures."""
    delay, tick_s = int(cfg[C_DELAY]), cfg[C_TICK_S]
    lo_s = (ks[PLANT_TICK] - delay) * tick_s
    n_iv = _intervals(ks, seg, cfg, lo_s, (ks[PLANT_TICK] + offsets[n_off - 1] - delay) * tick_s, iv)
    value, count, adc_max = 0, ks[HINT], int(cfg[C_ADC_MAX])
    for j in range(n_off - 1):
        y = _window_output(xl, px, pdd, sensor_steps, m, window, j, offsets[j], n_iv, iv)
        if noise_lsb == 0.0:
            count = adc_count(y, count, edges, adc_max)
            value += count
        else:
            v = np.floor(_analog(y, sp) + noise_lsb * z[z0 + j])
            value += int(min(max(v, 0.0), float(adc_max)))
    last = n_off - 1
    fs[READ_SENSOR] = _window_output(xl, px, pdd, sensor_steps, m, window, last, offsets[last], n_iv, iv)
    fs[READ_BLOCK] = _window_output(xl, bx, bdd, block_steps, m, window, last, offsets[last], n_iv, iv)
    ks[HINT] = count
    ks[ADC_VALUE] = value
    if cfg[C_MIN_SUM] <= value <= cfg[C_MAX_SUM]:
        ks[INVALID] = 0
    else:
        ks[INVALID] += 1


@inline
def _cut(ks, fs, seg, time_s, code):
    """Shutdown: the lane halts; the pin is off from time_s (queued values after it are dropped)."""
    cap = seg.shape[0]
    while ks[SEG_LEN] > 1 and seg[(ks[SEG_HEAD] + ks[SEG_LEN] - 1) % cap, 0] > time_s:
        ks[SEG_LEN] -= 1
    _queue(ks, seg, time_s, 0.0)
    ks[HALTED], ks[TRIP] = 1, code


@inline
def _queue(ks, seg, time_s, on_s):
    cap = seg.shape[0]
    if ks[SEG_LEN] < cap:
        slot = (ks[SEG_HEAD] + ks[SEG_LEN]) % cap
        seg[slot, 0], seg[slot, 1] = time_s, on_s
        ks[SEG_LEN] += 1


@inline
def _set_pwm(ks, fs, seg, cfg, read_time, value):
    """KlipperHeater.set_pwm: suppress small changes, else queue the value for read_time + pwm_delay."""
    if cfg[C_TARGET] <= 0.0:
        value = 0.0
    small_change = abs(value - fs[LAST_PWM]) < cfg[C_MIN_PWM_CHANGE]
    if small_change and (read_time < fs[NEXT_PWM_TIME] or not fs[LAST_PWM]):
        return
    pwm_time = read_time + cfg[C_PWM_DELAY]
    if cfg[C_RESEND_2025_08]:
        fs[NEXT_PWM_TIME] = pwm_time + cfg[C_MAX_HEAT] - (cfg[C_LOST_REPORTS] * cfg[C_PWM_DELAY] + 0.001)
    else:
        fs[NEXT_PWM_TIME] = pwm_time + 0.75 * cfg[C_MAX_HEAT]
    fs[LAST_PWM] = value
    on_ticks = int(max(0.0, min(1.0, value)) * cfg[C_CYCLE_TICKS] + 0.5)
    _queue(ks, seg, pwm_time, min(on_ticks, cfg[C_CYCLE_TICKS]) / cfg[C_CLOCK_HZ])


@inline
def _report(ks, fs, seg, cfg, g, read_time, temp):
    """KlipperHeater.temperature_callback: ControlPID, set_pwm, then the smoothed temperature."""
    time_diff = read_time - fs[LAST_TEMP_TIME]
    fs[LAST_TEMP], fs[LAST_TEMP_TIME] = temp, read_time
    target = cfg[C_TARGET]
    dt = read_time - fs[PREV_TEMP_TIME]
    temp_diff = temp - fs[PREV_TEMP]
    if dt >= cfg[C_SMOOTH]:
        temp_deriv = temp_diff / dt
    else:
        temp_deriv = (fs[PREV_DERIV] * (cfg[C_SMOOTH] - dt) + temp_diff) / cfg[C_SMOOTH]
    temp_err = target - temp
    temp_integ = fs[PREV_INTEG] + temp_err * dt
    temp_integ = max(0.0, min(g[G_INTEG_MAX], temp_integ))
    co = g[G_KP] * temp_err + g[G_KI] * temp_integ - g[G_KD] * temp_deriv
    bounded = max(0.0, min(cfg[C_MAX_POWER], co))
    _set_pwm(ks, fs, seg, cfg, read_time, bounded)
    fs[PREV_TEMP], fs[PREV_TEMP_TIME], fs[PREV_DERIV] = temp, read_time, temp_deriv
    if co == bounded:
        fs[PREV_INTEG] = temp_integ
    adj_time = min(time_diff * cfg[C_INV_SMOOTH], 1.0)
    fs[SMOOTHED] += (temp - fs[SMOOTHED]) * adj_time


@inline
def _verify(ks, fs, seg, cfg, eventtime):
    """VerifyHeater.check_event on the smoothed temperature (0 when stale); a fault shuts the lane down."""
    temp = 0.0 if fs[LAST_TEMP_TIME] < eventtime - cfg[C_STALE_S] else fs[SMOOTHED]
    target, hyst = cfg[C_TARGET], cfg[C_V_HYST]
    if temp >= target - hyst or target <= 0.0:
        ks[V_APPROACHING], ks[V_STARTING] = 0, 0
        if temp <= target + hyst:
            fs[V_ERROR] = 0.0
        fs[V_LAST_TARGET] = target
        return
    fs[V_ERROR] += (target - hyst) - temp
    if not ks[V_APPROACHING]:
        if target != fs[V_LAST_TARGET]:
            ks[V_APPROACHING], ks[V_STARTING] = 1, 1
            fs[V_GOAL_TEMP], fs[V_GOAL_TIME] = temp + cfg[C_V_GAIN], eventtime + cfg[C_V_GAIN_TIME]
        elif fs[V_ERROR] >= cfg[C_V_MAX_ERROR]:
            _cut(ks, fs, seg, eventtime, VERIFY_TRIP)
            return
    elif temp >= fs[V_GOAL_TEMP]:
        ks[V_STARTING] = 0
        fs[V_ERROR] = 0.0
        fs[V_GOAL_TEMP], fs[V_GOAL_TIME] = temp + cfg[C_V_GAIN], eventtime + cfg[C_V_GAIN_TIME]
    elif eventtime >= fs[V_GOAL_TIME]:
        ks[V_APPROACHING] = 0
    elif ks[V_STARTING]:
        fs[V_GOAL_TEMP] = min(fs[V_GOAL_TEMP], temp + cfg[C_V_GAIN])
    fs[V_LAST_TARGET] = target


@inline
def _duty_at(ks, seg, cfg, time_s):
    """SoftPwm.duty_at: the on-fraction of the value in force at time_s."""
    cap = seg.shape[0]
    for i in range(ks[SEG_LEN] - 1, -1, -1):
        slot = (ks[SEG_HEAD] + i) % cap
        if seg[slot, 0] <= time_s:
            return seg[slot, 1] / cfg[C_CYCLE_S]
    return 0.0


@inline
def _record(ks, fs, seg, cfg, read_time, r, score_i, score_f, score_p, flags, rec_temp, rec_duty, rec_sensor,
            rec_block, lane):
    """The report's row: a live lane's reading and duty, a halted lane's last ones held."""
    if not ks[HALTED]:
        fs[REC_TEMP], fs[REC_DUTY] = fs[LAST_TEMP], _duty_at(ks, seg, cfg, read_time)
    if cfg[C_RECORD]:
        rec_temp[lane, r], rec_duty[lane, r] = fs[REC_TEMP], fs[REC_DUTY]
        rec_sensor[lane, r], rec_block[lane, r] = fs[READ_SENSOR], fs[READ_BLOCK]
    if cfg[C_SCORE] and flags & 1:
        score_row(score_i, score_f, score_p, int(cfg[C_ROW_BASE]) + r, flags, fs[REC_TEMP], fs[REC_DUTY])


@inline
def _report_op(ks, fs, seg, cfg, g, plan, plan_t, q, temps, si, sf, score_p, rec_temp, rec_duty, rec_sensor,
               rec_block, lane):
    """A report: the MCU's pending shutdown first (it came at the window's last sample), then the host."""
    if not ks[HALTED] and not np.isnan(fs[SHUTDOWN_AT]):
        _cut(ks, fs, seg, fs[SHUTDOWN_AT], RANGE_TRIP)
    if not ks[HALTED]:
        _report(ks, fs, seg, cfg, g, plan_t[q, TIME], temps[ks[ADC_VALUE]])
    _record(ks, fs, seg, cfg, plan_t[q, TIME], plan[q, ROW], si, sf, score_p, plan[q, FLAGS], rec_temp, rec_duty,
            rec_sensor, rec_block, lane)


@inline
def _plant_bin(xl, io, cfg, n_bins):
    """The model a radiating lane runs from here: its block's bin from C_BIN_LO (0 when linear); n_bins
    when the tables lack it."""
    if not cfg[C_RADIATING]:
        return 0
    m = int(np.rint(output(io[0], 1, xl) * 2.0)) - int(cfg[C_BIN_LO])
    return m if 0 <= m < n_bins else n_bins


@jit
def run_lanes(todo, lane_ids, q_start, plan, plan_t, offsets, n_offsets, fx, fdd, px, pdd, bx, bdd, steps,
              sensor_steps, block_steps, io, edges, temps, sensor_p, cfg, gains, kstate, fstate, segments, x,
              noise_lsb, streams, z, score_i, score_f, score_p, rec_temp, rec_duty, rec_sensor, rec_block, iv,
              x_pair, stop, need_bin):
    """Every operation of ``plan`` from ``q_start[k]`` on each lane k of ``todo`` (its column of x,
    ``lane_ids[k]`` its row of the per-lane arrays); ``stop[k]``: where it stopped.

    plan (P, PLAN_COLUMNS) int64 and plan_t (P, 2): the operations in KlipperTwin's order. Tables by
    model m (radiating bin from ``cfg[C_BIN_LO]``) and kind: fx, fdd the runs' (RUN_KIND), px, pdd, bx,
    bdd the windows' (WINDOW_KIND, its tick offsets in ``offsets``); steps, sensor_steps,
    block_steps the heater's step responses; io the output rows. edges: the ADC's switching
    temperatures; temps: calc_temp of every sum; sensor_p: the thermistor (SP_* columns) for noisy
    lanes. segments (N, cap, 2): each lane's PWM values (time, on seconds). Noise: lane ``lane`` adds
    ``noise_lsb[lane]`` times ``z[streams[lane], ROW + j]`` to conversion j of an ADC row (its ROW: the
    window's first normal). Scratch: iv (MAX_INTERVALS, 2), x_pair (2, n_x).
    """
    xl, xn = x_pair[0], x_pair[1]
    n_bins = fx.shape[0]
    for k in todo:
        lane = lane_ids[k]
        ks, fs, g, seg = kstate[lane], fstate[lane], gains[lane], segments[lane]
        noise, zl = noise_lsb[lane], z[streams[lane]]
        si, sf = score_i[lane], score_f[lane]
        for i in range(x.shape[0]):
            xl[i] = x[i, k]
        q = q_start[k]
        while q < plan.shape[0]:
            op = plan[q, OP]
            if op == REPORT:
                _report_op(ks, fs, seg, cfg, g, plan, plan_t, q, temps, si, sf, score_p, rec_temp, rec_duty,
                           rec_sensor, rec_block, lane)
            elif op == VERIFY:
                if not ks[HALTED]:
                    _verify(ks, fs, seg, cfg, plan_t[q, TIME])
            elif not ks[HALTED]:  # ADC or ADVANCE: the plant runs to the operation's tick first
                m = _plant_bin(xl, io, cfg, n_bins)
                if m == n_bins:  # the block left the tables: KlipperBatch builds more bins
                    need_bin[k] = int(np.rint(output(io[0], 1, xl) * 2.0))
                    break
                _advance(ks, seg, cfg, xl, xn, fx, fdd, steps, m, plan[q, RUN_KIND], plan[q, TICK], iv)
                if op == ADC:
                    w = plan[q, WINDOW_KIND]
                    _adc(ks, fs, seg, cfg, xl, px, pdd, bx, bdd, sensor_steps, block_steps, m, w, offsets[w],
                         n_offsets[w], edges, iv, noise, zl, plan[q, ROW], sensor_p)
                    if ks[INVALID] >= cfg[C_RANGE_COUNT]:
                        fs[SHUTDOWN_AT] = plan_t[q, LAST_S]
            q += 1
        stop[k] = q
        for i in range(x.shape[0]):
            x[i, k] = xl[i]
