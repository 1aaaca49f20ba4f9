"""Full-stack benchmark: the 62.5 Hz loop against the emulated robot.

For each time scale: run the line trajectory (40 s robot time) through the driver against the
emulator in its own process, and report the loop period p50/p99/max (wall), overruns, missed
slots, the controller process's CPU share (setup included), the emulator's achieved time scale and tracking
errors. Run: ``.venv/bin/python bench/bench_stack.py [--scales 1,2,5] [--trajectory line] [--log]``;
prints a Markdown table to paste into BENCHMARKS.md.

``--lockstep``: runs in lockstep (robot time owned by the emulator, as fast as the host
allows) instead: the real-time factor of the full stack (robot s per wall s over the loop), of
the emulator's physics alone (robot s per CPU s of physics steps), the bus time per cycle and
the loop's host CPU per cycle; ``--repeat N`` runs it N times (the machine is shared: the
spread and the load average before and after each run say how much the neighbours cost),
``--emulator-config`` picks the physics profile (default ``ideal``).
"""
from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from benchutil import cpu_model


def main() -> None:
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    ap = argparse.ArgumentParser()
    ap.add_argument("--scales", default="1,2,3,4,5,6,8,10")
    ap.add_argument("--trajectory", default="line")
    ap.add_argument("--log", action="store_true", help="write the run log (as swerve demo and the tests do)")
    ap.add_argument("--lockstep", action="store_true", help="runs in lockstep: real-time factors")
    ap.add_argument("--repeat", type=int, default=1, help="lockstep: number of runs (default 1)")
    ap.add_argument("--emulator-config", default="ideal", help="lockstep: physics profile or file (default ideal)")
    args = ap.parse_args()
    print(f"date {time.strftime('%Y-%m-%d %H:%M')}, nproc {os.cpu_count()}, CPU {cpu_model()}, "
          f"Python {platform.python_version()}, load {os.getloadavg()[0]:.1f} at start, "
          f"trajectory {args.trajectory}, log {'on' if args.log else 'off'}")
    tmp = tempfile.TemporaryDirectory()
    if args.lockstep:
        print(f"physics profile {args.emulator_config}")
        print("| run | robot s | wall s | full-stack real-time factor | physics-only real-time factor "
              "| loop period p50 / max ms (robot) | overruns | host CPU per cycle p50 / p99 ms "
              "| host-CPU overruns | rms / final error mm | completed | load 1 min before / after |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        breakdown = []
        for k in range(args.repeat):
            log = Path(tmp.name) / f"run_{k}" if args.log else None
            load0 = os.getloadavg()[0]
            res = run_tracking(RunRequest(trajectory=args.trajectory, emulate=True, lockstep=True, time_scale=None,
                                          log=log, emulator_config=args.emulator_config))
            s = res.summary.to_dict()
            print(f"| {k + 1} | {s['cycles'] * s['loop_period_target_ms'] / 1e3:.1f} | {s['wall_time_s']:.1f} | "
                  f"{s['real_time_factor']:.1f} | {s.get('emulator_physics_real_time_factor', float('nan')):.1f} | "
                  f"{s['loop_period_p50_ms']:.2f} / {s['loop_period_max_ms']:.2f} | {s['overruns']} | "
                  f"{s['host_cpu_p50_ms']:.2f} / {s['host_cpu_p99_ms']:.2f} | {s['host_cpu_overruns']} | "
                  f"{1e3 * s['rms_position_error_m']:.1f} / {1e3 * s['final_position_error_m']:.1f} | "
                  f"{'yes' if s.get('completed') else 'no: ' + str(s.get('abort_cause'))} | "
                  f"{load0:.1f} / {os.getloadavg()[0]:.1f} |", flush=True)
            breakdown.append(_cycle_breakdown(k + 1, s))
        print("\nWhere one cycle's wall time goes, ms per 16 ms cycle (means over the run; the two "
              "processes mostly take turns, so the rest is hand-overs between them and waiting):")
        print("| run | wall | controller process (loop CPU, log included) | emulator process | "
              "of which physics | emulator bus, control, select | rest |")
        print("|---|---|---|---|---|---|---|")
        for row in breakdown:
            print(row)
        return
    print("| time scale | period target ms | p50 / p99 / max ms | overruns | missed slots | controller CPU % "
          "| emulator achieved scale | lost sim s | rms / final error mm | completed |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, scale in enumerate(float(s) for s in args.scales.split(",")):
        c0, w0 = time.process_time(), time.monotonic()
        log = Path(tmp.name) / f"run_{k}" if args.log else None
        res = run_tracking(RunRequest(trajectory=args.trajectory, emulate=True, time_scale=scale, log=log))
        cpu = (time.process_time() - c0) / (time.monotonic() - w0)
        s = res.summary.to_dict()
        print(f"| {scale:g} | {s['loop_period_target_ms']:.1f} | {s['loop_period_p50_ms']:.2f} / "
              f"{s['loop_period_p99_ms']:.2f} / {s['loop_period_max_ms']:.1f} | {s['overruns']} | "
              f"{s['missed_slots']} | {100 * cpu:.0f} | {s.get('emulator_achieved_time_scale', float('nan')):.2f} | "
              f"{s.get('emulator_lost_sim_s', float('nan')):.2f} | "
              f"{1e3 * s.get('rms_position_error_m', float('nan')):.1f} / "
              f"{1e3 * s.get('final_position_error_m', float('nan')):.1f} | "
              f"{'yes' if s.get('completed') else 'no: ' + str(s.get('abort_cause'))} |", flush=True)


def _cycle_breakdown(run: int, s: dict) -> str:
    """One Markdown row: a lockstep run's wall time per cycle split by process (ms)."""
    n = s["cycles"]
    wall = 1e3 * s["wall_time_s"] / n
    client = s["host_cpu_p50_ms"]
    emu = 1e3 * s["emulator_cpu_s"] / n if s.get("emulator_cpu_s") is not None else float("nan")
    physics = s["loop_period_target_ms"] / s["emulator_physics_real_time_factor"]
    return (f"| {run} | {wall:.2f} | {client:.2f} | {emu:.2f} | {physics:.2f} | {emu - physics:.2f} | "
            f"{wall - client - emu:.2f} |")


if __name__ == "__main__":
    main()
