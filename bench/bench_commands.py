"""Benchmark: whole commands as a user runs them, and how a lockstep cycle's cost divides.

Usage::

    python bench/bench_commands.py [--repeat 3] [--python PY ...] [--demo]

Each case runs ``swerve run --trajectory line --emulate --lockstep [--emulator-config realistic]
--log DIR --json`` in a fresh interpreter (a new log folder per run), with numba and with
``SWERVE_NO_JIT=1``, ``--repeat`` times, and reports medians of:

- ``whole``: wall time of the command, start to exit, s, and robot time / that (``× whole``);
- ``startup``: from the moment the benchmark starts the command to the loop's first cycle
  (``loop_started_unix_s`` of the summary), s: interpreter, imports, the emulator child's start,
  the gains, the log's opening, the servos' configuration and the steer to the start angles;
- ``loop``: the tracking loop's own wall time (``wall_time_s`` of the summary), and ``× loop``;
- ``exit``: whole − startup − loop: stopping the wheels, closing the log, reaping the child;
- ``outside``: whole − loop, start-up plus exit (also for a checkout whose summary does not
  give ``loop_started_unix_s`` and ``loop_cpu_s``, whose columns stay empty);
- per cycle (ms, means over the loop): ``loop`` (wall), ``controller`` (the controller
  process's CPU, ``loop_cpu_s``: the law, the log, the driver's encoding and its system calls),
  ``emulator`` (the emulator process's CPU serving the bus, physics included), ``physics``
  (the physics steps' CPU, from the emulator's physics real-time factor) and ``wait`` (loop −
  controller: the wall time the loop is not computing but waiting on the pty and the lockstep
  socket, which is when the emulator computes, plus the hand-overs between the processes).
  The two processes run on two CPUs and their work overlaps in part (the emulator answers a
  write while the controller logs), so controller + emulator can exceed loop; wait − emulator
  is the hand-over time only where they do not overlap.

The Riccati cache (``$XDG_CACHE_HOME/swerve``) is a folder of the benchmark's own, filled by an
untimed first run of each case (which also leaves numba's kernels in the checkout's
``__pycache__``); ``--cold-cache`` gives every run an empty one instead. The commands run with Python's bytecode
cache as an installed package has it: ``PYTHONDONTWRITEBYTECODE`` is removed from their
environment (without ``.pyc`` files every process compiles swerve's modules anew, ~0.1 s each).
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


def command_env(extra: dict[str, str]) -> dict[str, str]:
    """The environment of a timed command: this one with ``extra``, bytecode caching on."""
    env = {**os.environ, **extra}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run_line(python: str, profile: str, env: dict[str, str], workdir: Path) -> dict[str, float]:
    """One ``swerve run`` of the line in lockstep with a log; its timings (see module doc)."""
    log = Path(tempfile.mkdtemp(dir=workdir)) / "log"
    cmd = [python, "-m", "swerve.tools.cli", "run", "--trajectory", "line", "--emulate", "--lockstep",
           "--emulator-config", profile, "--log", str(log), "--json"]
    t0_unix, t0 = time.time(), time.perf_counter()
    out = subprocess.run(cmd, env=command_env(env), capture_output=True, text=True, check=True, cwd=workdir)
    whole = time.perf_counter() - t0
    s = json.loads(out.stdout)
    robot_s = s["real_time_factor"] * s["wall_time_s"]
    cycles = s["cycles"]
    loop_ms = 1e3 * s["wall_time_s"] / cycles
    out = {"whole_s": whole, "x_whole": robot_s / whole, "loop_s": s["wall_time_s"],
           "x_loop": s["real_time_factor"], "outside_s": whole - s["wall_time_s"], "loop_ms": loop_ms,
           "emulator_ms": 1e3 * s["emulator_cpu_s"] / cycles,
           "physics_ms": 1e3 * robot_s / s["emulator_physics_real_time_factor"] / cycles}
    if "loop_started_unix_s" in s:
        startup = s["loop_started_unix_s"] - t0_unix
        controller_ms = 1e3 * s["loop_cpu_s"] / cycles
        out.update(startup_s=startup, exit_s=whole - startup - s["wall_time_s"], controller_ms=controller_ms,
                   wait_ms=loop_ms - controller_ms)
    return out


def run_demo(python: str, workdir: Path) -> dict[str, float]:
    """``swerve demo``'s wall time, s."""
    t0 = time.perf_counter()
    subprocess.run([python, "-m", "swerve.tools.cli", "demo"], env=command_env({}), capture_output=True, check=True,
                   cwd=workdir)
    return {"whole_s": time.perf_counter() - t0}


def table(results: dict[tuple[str, str], list[dict[str, float]]]) -> str:
    """A markdown table of the medians per (python, case)."""
    keys = ("whole_s", "x_whole", "startup_s", "loop_s", "x_loop", "exit_s", "outside_s", "loop_ms",
            "controller_ms", "emulator_ms", "physics_ms", "wait_ms")
    lines = ["| python | case | " + " | ".join(keys) + " |", "|---" * (len(keys) + 2) + "|"]
    for (python, case), runs in results.items():
        cells = []
        for k in keys:
            vals = [r[k] for r in runs if k in r]
            cells.append(f"{statistics.median(vals):.3g}" if vals else "")
        lines.append(f"| {python} | {case} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def ratios(results: dict[tuple[str, str], list[dict[str, float]]], pythons: list[str]) -> str:
    """A markdown table of median(first python) / median(each other python) per case, for the
    columns both measure (> 1: the other is faster)."""
    keys = ("whole_s", "startup_s", "outside_s", "loop_s")
    lines = ["| case | python | " + " | ".join(f"{k} ratio" for k in keys) + " |", "|---" * (len(keys) + 2) + "|"]
    cases = dict.fromkeys(case for _, case in results)
    for case in cases:
        base = results.get((pythons[0], case), [])
        for python in pythons[1:]:
            cells = []
            for k in keys:
                a = [r[k] for r in base if k in r]
                b = [r[k] for r in results.get((python, case), []) if k in r]
                cells.append(f"{statistics.median(a) / statistics.median(b):.2f}" if a and b else "")
            lines.append(f"| {case} | {python} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--python", nargs="+", default=[sys.executable],
                    help="interpreters to compare (each with swerve installed)")
    ap.add_argument("--cases", default=",".join(c for c, _, _ in CASES),
                    help="comma-separated subset of: " + ", ".join(c for c, _, _ in CASES))
    ap.add_argument("--demo", action="store_true", help="also time `swerve demo`")
    ap.add_argument("--cold-cache", action="store_true",
                    help="a fresh $XDG_CACHE_HOME for every run (default: one for the whole benchmark, "
                         "filled by an untimed first run of each case)")
    args = ap.parse_args(argv)
    args.python = [os.path.abspath(p) for p in args.python]     # the runs start in a temporary folder
    chosen = [c for c in CASES if c[0] in args.cases.split(",")]
    results: dict[tuple[str, str], list[dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        cache = {"XDG_CACHE_HOME": str(workdir / "cache")}
        if not args.cold_cache:             # Riccati solutions (and numba's kernels) are in place
            for name, profile, env in chosen:
                for python in args.python:
                    run_line(python, profile, {**env, **cache}, workdir)
        for rep in range(args.repeat):
            for name, profile, env in chosen:
                for python in args.python:
                    if args.cold_cache:
                        cache = {"XDG_CACHE_HOME": tempfile.mkdtemp(dir=workdir)}
                    r = run_line(python, profile, {**env, **cache}, workdir)
                    results.setdefault((python, name), []).append(r)
                    print(f"[{rep + 1}/{args.repeat}] {python} {name}: {r['whole_s']:.2f} s whole, "
                          f"{r['x_whole']:.1f}x", file=sys.stderr, flush=True)
            if args.demo:
                for python in args.python:
                    results.setdefault((python, "demo"), []).append(run_demo(python, workdir))
    print(f"{time.strftime('%Y-%m-%d %H:%M')} UTC, {os.cpu_count()} CPUs, repeat {args.repeat} (medians)\n")
    print(table(results))
    if len(args.python) > 1:
        print(f"\nratios {args.python[0]} / other (same minutes)\n")
        print(ratios(results, args.python))
    return 0


if __name__ == "__main__":
    sys.exit(main())
