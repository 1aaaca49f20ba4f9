"""The USB adapter in the bus budget, measured in lockstep robot time (exact, the same on every machine).

Part 1: the loop's bus exchanges alone. The shipped robot's eight servos (register-only
emulator, in lockstep, Return Delay as the robot file sets it), driven by the driver's
:class:`~swerve.driver.wheelset.WheelSet` as the loop drives them: one read of present current,
velocity and position (Sync Read, or Fast Sync Read with ``--fast-read``) and one Bulk Write of
the goals per 16 ms slot. Robot time of the read (request out to last reply byte at the host)
and of the whole cycle's bus work, per adapter latency timer (none, 1 ms, 16 ms).

Part 2: the whole command, ``swerve run --trajectory line --emulate --lockstep
--adapter-latency-ms MS`` for each latency: overruns, missed slots, loop period and tracking.

Run: ``.venv/bin/python bench/bench_adapter.py [--cycles 200] [--latencies none,1,16] [--no-runs]``;
prints Markdown tables to paste into BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import time

from benchutil import cpu_model

PERIOD_S = 0.016


def bus_times(latency_ms: int | None, cycles: int, fast: bool) -> tuple[list[float], list[float]]:
    """``(read_s, cycle_s)`` per cycle in robot time, through an adapter at ``latency_ms``."""
    from swerve.configs import shipped
    from swerve.driver.bus import Bus
    from swerve.driver.robot_config import load_robot_config
    from swerve.driver.wheelset import WheelSet
    from swerve.emulator.factory import build_emulator
    from swerve.emulator.timing import Lockstep
    from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock

    cfg = load_robot_config(shipped("robot.yaml"))
    read_s, cycle_s = [], []
    if latency_ms is None:                              # the host reads the cable directly
        cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, adapter_latency_ms=None))
    with build_emulator(cfg, timing=Lockstep(), adapter_latency_ms=latency_ms) as emu:
        with LockstepLoopClock(emu.control.path) as clock, Bus(emu.port, cfg.link.baud, default_model=cfg.model,
                                                           timeout_margin_s=LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
            clock.attach(bus)           # its reply gate: a loaded host delays, never loses, a reply
            wheels = WheelSet(bus, cfg, fast=fast)
            wheels.configure()
            t0 = (int(clock.now() / PERIOD_S) + 1) * PERIOD_S
            for k in range(cycles):
                clock.sleep_until(t0 + k * PERIOD_S)
                a = clock.now()
                wheels.read_state()
                b = clock.now()
                wheels.write_goals([0.0] * 4, [0.0] * 4)
                c = clock.now()
                read_s.append(b - a)
                cycle_s.append(c - a)
    return read_s, cycle_s


def _ms(values: list[float]) -> str:
    lo, med, hi = min(values), statistics.median(values), max(values)
    return f"{lo * 1e3:.3f} / {med * 1e3:.3f} / {hi * 1e3:.3f}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=200)
    ap.add_argument("--latencies", default="none,1,16")
    ap.add_argument("--no-runs", action="store_true", help="skip part 2 (the line runs)")
    args = ap.parse_args()
    latencies = [None if x == "none" else int(x) for x in args.latencies.split(",")]
    print(f"date {time.strftime('%Y-%m-%d %H:%M')}, nproc {os.cpu_count()}, CPU {cpu_model()}, "
          f"Python {platform.python_version()}; robot time in lockstep (identical on any machine)")
    print("\n| adapter latency timer | read | min / median / max read ms | min / median / max cycle bus ms "
          "| cycles over 16 ms |")
    print("|---|---|---|---|---|")
    for fast in (False, True):
        for lat in latencies:
            read_s, cycle_s = bus_times(lat, args.cycles, fast)
            over = sum(c > PERIOD_S for c in cycle_s)
            print(f"| {'none (cable)' if lat is None else f'{lat} ms'} | {'Fast Sync Read' if fast else 'Sync Read'} "
                  f"| {_ms(read_s)} | {_ms(cycle_s)} | {over} of {len(cycle_s)} |", flush=True)
    if args.no_runs:
        return
    import tempfile
    from pathlib import Path

    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    print("\n`swerve run --trajectory line --emulate --lockstep --adapter-latency-ms MS` (ideal physics):")
    print("| adapter latency timer | cycles | overruns | missed slots | loop period p50 / max ms (robot) "
          "| rms / final error mm | wall s |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for lat in [x for x in latencies if x is not None]:
            w0 = time.monotonic()
            s = run_tracking(RunRequest(trajectory="line", emulate=True, lockstep=True, time_scale=None,
                                        log=Path(tmp) / f"l{lat}", adapter_latency_ms=lat)).summary.to_dict()
            print(f"| {lat} ms | {s['cycles']} | {s['overruns']} | {s['missed_slots']} | "
                  f"{s['loop_period_p50_ms']:.2f} / {s['loop_period_max_ms']:.2f} | "
                  f"{1e3 * s['rms_position_error_m']:.1f} / {1e3 * s['final_position_error_m']:.1f} | "
                  f"{time.monotonic() - w0:.1f} |", flush=True)


if __name__ == "__main__":
    main()
