"""The segments of a log worth fitting: heat-ups with their hold (Klipper Stats), pulses (heattests),
runs of M303 status reports with the relay's switches reconstructed, a plain CSV as a whole.

Inputs: duty is 0..1 of full power. Open-loop segments (heat-ups at full power, pulse tests,
multi-level runs) are the best data. In closed-loop segments the duty is what the controller set.
Klipper Stats log the last pwm *sent* to the MCU: Klipper holds back a change under 5 % of
max_power until its next resend, 2.1 to 3.75 s later depending on the version
(firmware_port/klipper/heater.py), and the 1 Hz line samples a 0.3 s control signal. That value
is the input here all the same; the residuals carry its error.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from tools.ident.relay_trace import relay_target_c, switch_instants
from tools.logs import HeaterSeries, HeattestLog, Log, M303Log, PlainLog, StatsLog

# Segments of a log
SATURATION_TOL = 0.0005  # Klipper prints pwm with 3 decimals: at max_power within this
MIN_HEATUP_S = 10.0  # a run at max_power this long starts a heat-up (shorter ones are PID bumps)
HOLD_AFTER_S = 300.0  # a segment ends this long after its heat-up (or its start): the hold, before a print's load
MIN_SAMPLES = 20
M303_MIN_SAMPLES = 12  # a relay trace: three 10 s cycles of 2 s status lines at least
M303_STATUS_PERIOD_S = 2.0  # Marlin reports every 2 s during M303 (hardware_logs README D)
M303_MAX_LINE_STEP = 7  # bias, Ku/Tu, rule and Kp/Ki/Kd lines between two reports; more: a gap

class Segment(NamedTuple):
    """A stretch of a log to fit: sample instants, readings, and the duty held from each sample to the next."""

    label: str
    t_s: np.ndarray
    temp_c: np.ndarray
    duty: np.ndarray  # 0..1 of full power
    fan: float = 0.0  # part fan 0..1 (the lumped models' fan_ambient_xfer_w_k)
    note: str = ""  # what the input is: open loop, closed loop, relay
    full_power_s: float = 0.0  # time at max_power: the open-loop part
    cools_at_full_power: bool = False  # the reading fell while at max_power: the heater did not heat
    observed: np.ndarray | None = None  # False at inserted samples (relay switch instants): not compared
    target_c: float = math.nan  # an M303 relay's target
    target_source: str = ""  # where target_c comes from (tools/ident/relay_trace.py relay_target_c)
    line_nos: np.ndarray | None = None  # an M303 trace: the status line of each sample (a switch: the next line's)

    def before_line(self, line_no: int) -> Segment:
        """The samples before a line of the capture (an M303 trace: the cycles printed up to it)."""
        if self.line_nos is None:
            raise ValueError("a segment without line numbers cannot be cut at a line")
        keep = self.line_nos < line_no
        return self._replace(t_s=self.t_s[keep], temp_c=self.temp_c[keep], duty=self.duty[keep],
                             observed=None if self.observed is None else self.observed[keep],
                             line_nos=self.line_nos[keep])

    def decimated(self, max_samples: int) -> Segment:
        """At most max_samples samples: every k-th kept, the duty of each kept interval the time
        average of the logged duty over it (the heat it brings is kept; its timing within the interval
        is not), the note saying so. A segment that short already is returned as it is."""
        n = len(self.t_s)
        if n <= max_samples:
            return self
        keep = np.unique(np.r_[np.arange(0, n, math.ceil(n / max_samples)), n - 1])
        energy = np.r_[0.0, np.cumsum(self.duty[:-1] * np.diff(self.t_s))]  # duty x time up to each sample
        duty = np.r_[np.diff(energy[keep]) / np.diff(self.t_s[keep]), self.duty[-1]]
        step_s = float(np.median(np.diff(self.t_s[keep])))
        note = f"{self.note}; decimated from {n} to {len(keep)} samples ({step_s:.3g} s apart, duty averaged over each)"
        return self._replace(t_s=self.t_s[keep], temp_c=self.temp_c[keep], duty=duty, note=note,
                             observed=None if self.observed is None else self.observed[keep], line_nos=None)


def default_segment(segments: Sequence[Segment]) -> int:
    """The first segment with at least half the longest time at max_power (the most open-loop data),
    among those where full power heats."""
    usable = [seg for seg in segments if not seg.cools_at_full_power] or list(segments)
    most_s = max(seg.full_power_s for seg in usable)
    return next(i for i, seg in enumerate(segments) if seg in usable and seg.full_power_s >= 0.5 * most_s)


class NotFittable(ValueError):
    """A log, or a part of one, that holds no temperature-and-duty series to fit; says why."""


# --- what a log offers ---------------------------------------------------------------------------


def _segment(label: str, t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, max_power: float, between: str,
             extra: str = "") -> Segment:
    """A Segment noting its seconds at max_power, off and in between (duty held from each sample to the next)."""
    held_s = np.diff(t_s)
    u = duty[:-1]
    full = u >= max_power - SATURATION_TOL
    parts = [(f"at max_power {max_power:g}" if max_power < 1 else "full power", held_s[full].sum()),
             ("off", held_s[u == 0].sum()), (f"in between ({between})", held_s[~full & (u > 0)].sum())]
    cools = bool(full.any() and np.diff(temp_c)[full].sum() < 0)
    note = (", ".join(f"{what} {s:.0f} s" for what, s in parts if s) + extra
            + ("; the reading FALLS at full power: the heater did not heat (a fault?)" if cools else ""))
    return Segment(f"{label}{t_s[0]:.1f}..{t_s[-1]:.1f} s", t_s, temp_c, duty, note=note,
                   full_power_s=float(held_s[full].sum()), cools_at_full_power=cools)


def split_heatups(label: str, t_s: np.ndarray, temp_c: np.ndarray, duty: np.ndarray, max_power: float = 1.0,
                  between: str = "closed loop", target_c: np.ndarray | None = None) -> list[Segment]:
    """Segments of one gap-free series: from the heater's first turn-on and from each heat-up (a run at
    max_power of MIN_HEATUP_S or more) to the next, each cut HOLD_AFTER_S after its heat-up (or
    its start), and at the first change of target_c after it (a print starting changes the load);
    those of fewer than MIN_SAMPLES samples are left out."""
    full = duty >= max_power - SATURATION_TOL
    on = np.flatnonzero(duty > 0)
    if not on.size:
        return []
    last = len(t_s) - 1
    runs: list[list[int]] = []  # [start, end) at max_power, dips shorter than MIN_HEATUP_S bridged
    starts, ends = np.flatnonzero(full & ~np.r_[False, full[:-1]]), np.flatnonzero(full & ~np.r_[full[1:], False]) + 1
    for run_start, run_end in zip(starts.tolist(), ends.tolist()):
        if runs and t_s[run_start] - t_s[runs[-1][1]] < MIN_HEATUP_S:
            runs[-1][1] = run_end
        else:
            runs.append([run_start, run_end])
    heatups = {s: e for s, e in runs if t_s[min(e, last)] - t_s[s] >= MIN_HEATUP_S}
    bounds = sorted({int(on[0])} | {int(s) for s in heatups if s >= on[0]}) + [len(t_s)]
    segments = []
    for start, stop in itertools.pairwise(bounds):
        settled_s = t_s[min(heatups.get(start, start), last)]
        stop = min(stop, int(np.searchsorted(t_s, settled_s + HOLD_AFTER_S, side="right")))
        if target_c is not None:
            settled = int(np.searchsorted(t_s, settled_s))
            changes = np.flatnonzero(target_c[settled:stop] != target_c[settled])
            stop = settled + int(changes[0]) if changes.size else stop
        if stop - start >= MIN_SAMPLES:
            segments.append(_segment(label, t_s[start:stop], temp_c[start:stop], duty[start:stop], max_power,
                                     between))
    return segments


def _stats_segments(log: StatsLog, heater: str | None, session: int | None) -> tuple[str, list[Segment]]:
    names = sorted({name for s in log.sessions for name in s})
    heater = heater or ("extruder" if "extruder" in names else names[0])
    if heater not in names:
        raise NotFittable(f"no heater {heater!r} in this Klipper log; it has {', '.join(names)}")
    if session is not None and not 0 <= session < len(log.sessions):
        raise NotFittable(f"no session {session}: the log has sessions 0..{len(log.sessions) - 1}")
    max_power = float(log.meta["config"].get(heater, {}).get("max_power", 1.0))
    segments = []
    for index, heaters in enumerate(log.sessions):
        series: HeaterSeries | None = heaters.get(heater)
        if series is None or session not in (None, index):
            continue
        for part in series.segments():
            segments += split_heatups(f"session {index}, ", part.t_s, part.temp_c, part.pwm, max_power,
                                      "closed loop: the pwm Klipper last sent", part.target_c)
    if not segments:
        where = f"session {session}" if session is not None else "any session"
        raise NotFittable(f"{heater} never heats for {MIN_SAMPLES} or more Stats lines in {where}")
    return heater, segments


def _relay_segment(log: M303Log, run: list, heater_key: str) -> Segment:
    """A run of status lines as a Segment, 2 s apart, the relay's switches reconstructed (tools/ident/relay_trace.py)."""
    t_s = M303_STATUS_PERIOD_S * np.arange(len(run))
    temp_c = np.array([s.temp_c for s in run])
    duty = np.array([s.power for s in run]) / log.power_max
    found = relay_target_c(log, heater_key, run[0].line_no, (temp_c, duty > duty.min()))
    seg = _segment(f"lines {run[0].line_no}..{run[-1].line_no}, ", t_s, temp_c, duty, 1.0, "relay levels",
                   f"; {M303_STATUS_PERIOD_S:g} s per status line, which carry no time")
    if found is None:
        return seg
    target_c, how = found
    lines = np.array([s.line_no for s in run])
    switched_t_s, temp_c, duty, observed = switch_instants(t_s, temp_c, duty, target_c)
    line_nos = lines[np.searchsorted(t_s, switched_t_s)]  # an inserted switch: the status line after it
    t_s = switched_t_s
    # Before the first switch the fit's start (every node at one temperature) is wrong mid-cycle: a
    # burn-in, simulated but not compared.
    observed[: int(np.argmin(observed))] = False
    note = f"{seg.note}; relay target {target_c:g} C ({how}), switches put at its crossings, compared from the first"
    return seg._replace(t_s=t_s, temp_c=temp_c, duty=duty, observed=observed, target_c=target_c, target_source=how,
                        note=note, line_nos=line_nos)


def _m303_segments(log: M303Log, heater: str | None) -> tuple[str, list[Segment]]:
    """Runs of a heater's 2 s status reports, cut where lines are missing; by default the
    extruder's, else the bed's."""
    keys = {"extruder": "T", "heater_bed": "B"}
    if heater is not None and heater not in keys:
        raise NotFittable(f"Marlin console text has heaters {', '.join(keys)}, not {heater!r}")
    cut_lines = np.array([no for no, _ in log.skipped])
    for name in [heater] if heater else keys:
        runs: list[list] = []
        status = [s for s in log.status if s.heater == keys[name]]
        for s in status:
            prev = runs[-1][-1].line_no if runs else -M303_MAX_LINE_STEP
            if s.line_no - prev > M303_MAX_LINE_STEP or np.any((cut_lines > prev) & (cut_lines < s.line_no)):
                runs.append([])
            runs[-1].append(s)
        segments = [_relay_segment(log, run, keys[name]) for run in runs if len(run) >= M303_MIN_SAMPLES]
        if segments:
            return name, segments
    raise NotFittable(f"Marlin autotune output with {len(log.cycles)} relay cycles and {len(log.status)} status "
                      f"lines{' of the ' + heater if heater else ''}: no run of {M303_MIN_SAMPLES} or more status "
                      "reports (T:/B: and @:) to fit")


def log_segments(log: Log, heater: str | None = None, session: int | None = None) -> tuple[str, list[Segment]]:
    """The heater (default: extruder) and its segments worth fitting, in the log's order.

    Klipper Stats: each gap-free run of a session split at heat-ups (runs at max_power); heattests
    the same (each pulse and its cooling, open loop); Marlin M303 text: runs of 2 s status reports;
    a plain CSV: the whole series. NotFittable says why a log has none.
    """
    if isinstance(log, StatsLog):
        return _stats_segments(log, heater, session)
    if isinstance(log, M303Log):
        return _m303_segments(log, heater)
    if isinstance(log, HeattestLog):
        segments = split_heatups("", log.t_s, log.temp_c, log.pwm)
    elif isinstance(log, PlainLog):
        segments = [_segment("", log.t_s, log.temp_c, log.duty, 1.0, "as logged")]
    else:
        raise NotFittable("Klipper PID_CALIBRATE results: PID gains only, no temperature trace")
    if not segments:
        raise NotFittable("the heater never turns on for long enough in this log")
    return heater or "extruder", segments
