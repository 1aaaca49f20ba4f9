"""Benchmark: whole commands as a user runs them, and how a lockstep cycle's cost divides.

Usage::

    python bench/bench_commands.py [--repeat 3] [--python PY ...] [--demo]

Each case runs ``swerve run --trajectory line --emulate --lockstep [--emulator-config realistic]
--log DIR --json`` in a fresh interpreter (a new log folder per run), with numba and with
``SWERVE_NO_JIT=1``, ``--repeat`` times, and reports medians of:

- ``whole``: wall time of the command, start to exit, s, and robot time / that (``× whole``);
- ``loop``: the tracking loop's own wall time (``wall_time_s`` of the summary), and ``× loop``;
- ``outside``: whole − loop: start-up before the first cycle plus the exit (stop, close, reap);
- per cycle (ms): ``controller`` (the loop's host CPU, median), ``emulator`` (the emulator
  process's CPU serving the bus, physics included, per cycle), ``physics`` (the physics steps'
  CPU per cycle, from the emulator's physics real-time factor) and ``bus + hand-overs`` (loop
  wall per cycle minus controller and emulator CPU: pty and socket round trips, scheduling).

``--python`` takes several interpreters (e.g. the venv of another checkout) and runs every case
with each, in turn within each repetition, so their ratio is measured in the same minutes of a
shared machine. ``--demo`` adds ``swerve demo`` (three realistic paths; its wall time).
Medians and ratios are what to quote on a loaded machine.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = (("ideal", "ideal", {}), ("realistic", "realistic", {}),
         ("ideal-nojit", "ideal", {"SWERVE_NO_JIT": "1"}),
         ("realistic-nojit", "realistic", {"SWERVE_NO_JIT": "1"}))


def run_line(python: str, profile: str, env: dict[str, str], workdir: Path) -> dict[str, float]:
    """One ``swerve run`` of the line in lockstep with a log; its timings (see module doc)."""
    log = Path(tempfile.mkdtemp(dir=workdir)) / "log"
    cmd = [python, "-m", "swerve.tools.cli", "run", "--trajectory", "line", "--emulate", "--lockstep",
           "--emulator-config", profile, "--log", str(log), "--json"]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env={**os.environ, **env}, capture_output=True, text=True, check=True, cwd=workdir)
    whole = time.perf_counter() - t0
    s = json.loads(out.stdout)
    robot_s = s["real_time_factor"] * s["wall_time_s"]
    cycles = s["cycles"]
    emulator_ms = 1e3 * s["emulator_cpu_s"] / cycles
    physics_ms = 1e3 * robot_s / s["emulator_physics_real_time_factor"] / cycles
    loop_ms = 1e3 * s["wall_time_s"] / cycles
    return {"whole_s": whole, "x_whole": robot_s / whole, "loop_s": s["wall_time_s"],
            "x_loop": s["real_time_factor"], "outside_s": whole - s["wall_time_s"],
            "controller_ms": s["host_cpu_p50_ms"], "emulator_ms": emulator_ms, "physics_ms": physics_ms,
            "bus_ms": loop_ms - s["host_cpu_p50_ms"] - emulator_ms}


def run_demo(python: str, workdir: Path) -> dict[str, float]:
    """``swerve demo``'s wall time, s."""
    t0 = time.perf_counter()
    subprocess.run([python, "-m", "swerve.tools.cli", "demo"], capture_output=True, check=True, cwd=workdir)
    return {"whole_s": time.perf_counter() - t0}


def table(results: dict[tuple[str, str], list[dict[str, float]]]) -> str:
    """A markdown table of the medians per (python, case)."""
    keys = ("whole_s", "x_whole", "loop_s", "x_loop", "outside_s", "controller_ms", "emulator_ms", "physics_ms",
            "bus_ms")
    lines = ["| python | case | " + " | ".join(keys) + " |", "|---" * (len(keys) + 2) + "|"]
    for (python, case), runs in results.items():
        cells = []
        for k in keys:
            vals = [r[k] for r in runs if k in r]
            cells.append(f"{statistics.median(vals):.3g}" if vals else "")
        lines.append(f"| {python} | {case} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--python", nargs="+", default=[sys.executable],
                    help="interpreters to compare (each with swerve installed)")
    ap.add_argument("--cases", default=",".join(c for c, _, _ in CASES),
                    help="comma-separated subset of: " + ", ".join(c for c, _, _ in CASES))
    ap.add_argument("--demo", action="store_true", help="also time `swerve demo`")
    args = ap.parse_args(argv)
    chosen = [c for c in CASES if c[0] in args.cases.split(",")]
    results: dict[tuple[str, str], list[dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        for rep in range(args.repeat):
            for name, profile, env in chosen:
                for python in args.python:
                    r = run_line(python, profile, env, workdir)
                    results.setdefault((python, name), []).append(r)
                    print(f"[{rep + 1}/{args.repeat}] {python} {name}: {r['whole_s']:.2f} s whole, "
                          f"{r['x_whole']:.1f}x", file=sys.stderr, flush=True)
            if args.demo:
                for python in args.python:
                    results.setdefault((python, "demo"), []).append(run_demo(python, workdir))
    print(f"{time.strftime('%Y-%m-%d %H:%M')} UTC, {os.cpu_count()} CPUs, repeat {args.repeat} (medians)\n")
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
