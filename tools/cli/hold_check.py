"""Gains checked as a user would check them: the public API's ``Twin`` heats a preset to a target and
holds it, with ADC noise, on several noise seeds; the verdict per gain set.

    python -m tools.cli.hold_check --plant hotend_cartridge --target 210 \\
        --gains 13,0.3,70 --gains 12.13,0.3684,99.89 --seeds 10 --noise 1

Per seed: a protection trip, the mean |duty change| per reading while holding (``chatter``) and the
mean |target - reading| while holding (``hold error``), "holding" being the readings from
``--hold-from`` seconds to the end (no disturbance: the plain hold a print starts from). A gain set
passes when no seed trips and every seed keeps chatter <= ``--max-chatter`` and the hold error
<= ``--max-hold`` (defaults 0.03 and 1 C: what a robust tune must hold). Exit status 0 when
every gain set passes, 1 otherwise.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from firmware_port.controller import KD_MAX, KI_MAX, KP_MAX
from tools.cli.args import ranged_float, ranged_int
from tools.entry import OneLineParser, run_main
from twin import PRESETS, PidGains, Twin
from twin.limits import DURATION_MAX_S, HEATER_MAX_C, NOISE_MAX_LSB, UserError

DURATION_S = 900.0
HOLD_FROM_S = 300.0
MAX_CHATTER = 0.03
MAX_HOLD_C = 1.0
AMBIENT_C = 25.0  # Twin.create's room: a target must lie above it
SEEDS_MAX = 1000


@dataclass(frozen=True)
class SeedRun:
    """One seed's heat-and-hold."""

    seed: int
    tripped: bool
    chatter: float
    hold_error_c: float
    overshoot_c: float


def hold_run(plant: str, target_c: float, gains: PidGains, seed: int, noise_lsb: float,
             duration_s: float = DURATION_S, hold_from_s: float = HOLD_FROM_S) -> SeedRun:
    """The gains on the preset through ``Twin``: heat to target_c, hold to duration_s."""
    twin = Twin.create("pid", hotend=plant, seed=seed, noise_lsb=noise_lsb, ambient_c=AMBIENT_C)
    twin.hotend.gains = gains
    twin.hotend.target_c = target_c
    hotend = twin.run(duration_s).hotend
    t_s, reading_c, duty = (np.asarray(a, float) for a in (hotend.t_s, hotend.measured_c, hotend.duty))
    holding = t_s >= hold_from_s
    return SeedRun(seed, bool(twin.board.halted), float(np.mean(np.abs(np.diff(duty[holding])))),
                   float(np.mean(np.abs(target_c - reading_c[holding]))), float(reading_c.max() - target_c))


def check_run(plant: str, target_c: float, duration_s: float) -> None:
    """Before any run: the firmware takes target_c as it is (no clamp to its maximum) and a run of
    duration_s keeps a trace that fits in memory; ValueError names the flag."""
    twin = Twin.create("pid", hotend=plant, ambient_c=AMBIENT_C)
    twin.hotend.target_c = target_c
    if twin.hotend.target_c != int(target_c):
        raise UserError(f"--target {target_c:g}: the firmware clamps it to {twin.hotend.target_c} C on {plant}")
    try:
        twin.check_horizon(duration_s)
    except ValueError as exc:
        raise UserError(f"--duration {duration_s:g}: {exc}") from None


def passes(runs: list[SeedRun], max_chatter: float = MAX_CHATTER, max_hold_c: float = MAX_HOLD_C) -> bool:
    return all(not r.tripped and r.chatter <= max_chatter and r.hold_error_c <= max_hold_c for r in runs)


def _gains(text: str) -> PidGains:
    """KP,KI,KD in Marlin's units, each finite and within what the firmware's fixed-point PID takes."""
    try:
        kp, ki, kd = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"KP,KI,KD in Marlin's units, got {text!r}") from None
    for name, value, high in (("KP", kp, KP_MAX), ("KI", ki, KI_MAX), ("KD", kd, KD_MAX)):
        if not 0.0 <= value <= high:  # false for NaN too
            raise argparse.ArgumentTypeError(f"{name} {value:g} in {text!r} is outside 0..{high:g}")
    return PidGains(kp, ki, kd)


def build_parser() -> OneLineParser:
    parser = OneLineParser(prog="python -m tools.cli.hold_check", description=__doc__.splitlines()[0],
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--plant", default="hotend_cartridge", choices=sorted(PRESETS), help="plant preset")
    parser.add_argument("--target", type=ranged_float(AMBIENT_C + 1.0, HEATER_MAX_C, "C"), default=210.0,
                        help="target, C")
    parser.add_argument("--gains", type=_gains, action="append", required=True, help="KP,KI,KD (repeat to compare)")
    parser.add_argument("--seeds", type=ranged_int(1, SEEDS_MAX), default=10, help="noise seeds 1..N")
    parser.add_argument("--noise", type=ranged_float(0.0, NOISE_MAX_LSB, "LSB"), default=1.0, help="ADC noise, LSB")
    parser.add_argument("--duration", type=ranged_float(1.0, DURATION_MAX_S, "s"), default=DURATION_S,
                        help="run length, s")
    parser.add_argument("--hold-from", type=ranged_float(0.0, DURATION_MAX_S, "s"), default=HOLD_FROM_S,
                        help="holding is scored from here, s")
    parser.add_argument("--max-chatter", type=ranged_float(0.0, 1.0, ""), default=MAX_CHATTER,
                        help="mean |duty change| per reading (a duty is 0..1)")
    parser.add_argument("--max-hold", type=ranged_float(0.0, HEATER_MAX_C, "C"), default=MAX_HOLD_C,
                        help="mean |error| while holding, C")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.hold_from < args.duration:
        parser.error(f"--hold-from {args.hold_from:g} must be before the end of the run (--duration {args.duration:g})")

    def run() -> int:
        check_run(args.plant, args.target, args.duration)
        verdicts = []
        print(f"{args.plant} at {args.target:g} C, ADC noise {args.noise:g} LSB, seeds 1..{args.seeds}, "
              f"holding from {args.hold_from:g} s to {args.duration:g} s (worst seed / mean):")
        for gains in args.gains:
            runs = [hold_run(args.plant, args.target, gains, seed, args.noise, args.duration, args.hold_from)
                    for seed in range(1, args.seeds + 1)]
            ok = passes(runs, args.max_chatter, args.max_hold)
            verdicts.append(ok)
            print(f"  Kp {gains.kp:g} Ki {gains.ki:g} Kd {gains.kd:g}: trips {sum(r.tripped for r in runs)} of {len(runs)}, "
                  f"chatter {max(r.chatter for r in runs):.4f} / {np.mean([r.chatter for r in runs]):.4f}, "
                  f"hold error {max(r.hold_error_c for r in runs):.3f} / {np.mean([r.hold_error_c for r in runs]):.3f} C, "
                  f"overshoot {max(r.overshoot_c for r in runs):.2f} C: {'PASS' if ok else 'FAIL'}")
        return 0 if all(verdicts) else 1

    return run_main(parser.prog, run)


if __name__ == "__main__":
    raise SystemExit(main())
