"""The lockstep emulator's cost per control cycle, with a scripted client.

A client in this process drives the emulated robot (its own process, as ``swerve run --emulate
--lockstep`` does) through the same calls the tracking loop makes each 16 ms cycle: a Sync Read
of the eight servos with a ``pose`` request sent right after it, a Bulk Write of goals (fixed
wheel speeds, a slow steering sweep) and an ``advance`` to the next deadline. Prints the
emulator process's CPU per cycle (all threads, from ``/proc``) and, of it, the physics
(the clock's ``cpu_s``).

Run: ``.venv/bin/python bench/bench_emu_serve.py [--cycles 2000] [--emulator-config ideal]``.
``--callgrind DIR``: run the emulator under ``valgrind --tool=callgrind`` (instrumented only
during the cycles, ``SWERVE_NO_JIT=1`` so no compiler runs under it) and print its instructions
per cycle; the profile is ``DIR/callgrind.out.<pid>`` (``callgrind_annotate`` reads it).
``--exclude step_many`` leaves the physics out of the count (any ``Emulator`` methods by name, or
``<Class>.<name>`` of ``ControlServer``, ``VirtualServo``, ``ServoMemory``, ``PacketParser``, ``ReplyPacer``).
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

STEP_S = 1e-3
PERIOD_S = 0.016


def _cpu_s(pid: int) -> tuple[float, float]:
    """User and system CPU of process ``pid`` so far, s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return int(fields[11]) / tick, int(fields[12]) / tick


def _profiled_command(out: Path) -> str:
    """The command line a callgrind profile names (its ``cmd:`` line)."""
    for line in out.read_text().splitlines():
        if line.startswith("cmd:"):
            return line[4:].strip()
    raise RuntimeError(f"no cmd in {out}")


def _callgrind_instructions(out: Path) -> int:
    """Total Ir of a callgrind profile (its ``totals:`` line)."""
    for line in out.read_text().splitlines():
        if line.startswith("totals:"):
            return int(line.split()[1])
    raise RuntimeError(f"no totals in {out}")


_TOGGLE_C = "#include <valgrind/callgrind.h>\nvoid toggle_collect(void) { CALLGRIND_TOGGLE_COLLECT; }\n"
_SITECUSTOMIZE = """\
import ctypes, functools
from swerve.driver.parser import PacketParser
from swerve.emulator.lockstep_socket import ControlServer
from swerve.emulator.memory import ServoMemory
from swerve.emulator.reply_pacing import ReplyPacer
from swerve.emulator.server import Emulator
from swerve.emulator.servo import VirtualServo
_classes = dict(PacketParser=PacketParser, ControlServer=ControlServer, ServoMemory=ServoMemory,
                VirtualServo=VirtualServo, ReplyPacer=ReplyPacer)
_toggle = ctypes.CDLL({lib!r}).toggle_collect
_depth = [0]
def _excluded(method):
    @functools.wraps(method)
    def call(*args, **kwargs):
        _depth[0] += 1
        if _depth[0] == 1:
            _toggle()
        try:
            return method(*args, **kwargs)
        finally:
            _depth[0] -= 1
            if _depth[0] == 0:
                _toggle()
    return call
for _name in {names!r}:
    _cls, _, _method = _name.rpartition(".")
    _cls = _classes.get(_cls, Emulator)
    setattr(_cls, _method, _excluded(getattr(_cls, _method)))
"""


def _build_exclusions(hook: Path, names: list[str]) -> None:
    """A ``sitecustomize`` in ``hook`` that stops callgrind collecting inside the
    methods ``names`` (of :class:`Emulator`, or ``<Class>.<name>`` of ``ControlServer``,
    ``VirtualServo``, ``ServoMemory``, ``PacketParser``, ``ReplyPacer``), by client requests
    from a small C library built here."""
    if not names:
        return
    (hook / "toggle.c").write_text(_TOGGLE_C)
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-o", str(hook / "toggle.so"), str(hook / "toggle.c")],
                   check=True)
    (hook / "sitecustomize.py").write_text(_SITECUSTOMIZE.format(lib=str(hook / "toggle.so"), names=names))


def main() -> None:
    from swerve.configs import locate_robot_file
    from swerve.driver.bus import Bus
    from swerve.driver.robot_config import load_robot_config
    from swerve.driver.wheelset import WheelSet
    from swerve.emulator.physics.profiles import resolve_emulator_config
    from swerve.emulator.process import EmulatorProcess
    from swerve.emulator.timing import Lockstep
    from swerve.tools.run.lockstep import LockstepLoopClock

    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=100, help="cycles before the measurement")
    ap.add_argument("--emulator-config", default="ideal")
    ap.add_argument("--callgrind", metavar="DIR", help="run the emulator under callgrind, profile in DIR")
    ap.add_argument("--exclude", default="", metavar="METHOD,...",
                    help="with --callgrind: count nothing inside these methods (Emulator's by name, "
                         "or Class.name; step_many: the physics runs)")
    args = ap.parse_args()
    if args.cycles < 1 or args.warmup < 0:
        ap.error("--cycles must be >= 1 and --warmup >= 0")
    if args.exclude and not args.callgrind:
        ap.error("--exclude needs --callgrind")
    if args.callgrind:
        needed = ["valgrind", "callgrind_control"] + (["gcc"] if args.exclude else [])
        missing = [tool for tool in needed if shutil.which(tool) is None]
        if missing:
            ap.error(f"--callgrind needs {', '.join(missing)} on PATH")

    if args.callgrind:
        out_dir = Path(args.callgrind).resolve()
        out_dir.mkdir(parents=True, exist_ok=True)
        hook_dir = tempfile.TemporaryDirectory(prefix="bench-emu-serve-")     # removed at exit
        hook = Path(hook_dir.name)
        _build_exclusions(hook, [n for n in args.exclude.split(",") if n])
        wrapper = hook / "python-callgrind"
        wrapper.write_text(f"#!/bin/sh\nPYTHONPATH={hook} exec valgrind --tool=callgrind --instr-atstart=no "
                           f"--callgrind-out-file={out_dir}/callgrind.out.%p {sys.executable} \"$@\"\n")
        wrapper.chmod(0o755)
        os.environ["SWERVE_NO_JIT"] = "1"

    robot = locate_robot_file(None).path
    cfg = load_robot_config(robot)
    emu = EmulatorProcess(robot, resolve_emulator_config(args.emulator_config), timing=Lockstep(),
                          noise="seed=1", rate_hz=1 / STEP_S)
    # the child is a fresh interpreter started as ``sys.executable`` (emulator/process.py):
    # under callgrind, the wrapper that runs it under valgrind
    with mock.patch.object(sys, "executable", str(wrapper)) if args.callgrind else contextlib.nullcontext():
        emu.launch()
    with emu, \
            LockstepLoopClock(emu.control_path) as clock, Bus(emu.port, cfg.link.baud, retries=0,
                                                          default_model=cfg.model,
                                                          timeout_margin_s=5.0) as bus:
        clock.attach(bus)
        wheels = WheelSet(bus, cfg)
        wheels.configure()
        wheels.enable()
        t = clock.align(STEP_S)

        def cycle(k: int) -> None:
            nonlocal t
            clock.ask_after_next_write()
            wheels.read_state()
            clock.now()
            clock.pose()
            wheels.write_goals([2.0] * 4, [0.3 * math.sin(0.01 * k)] * 4)
            t += PERIOD_S
            clock.start_sleep(t)
            clock.end_sleep()

        for k in range(args.warmup):
            cycle(k)
        pid = emu.pid
        if args.callgrind:
            subprocess.run(["callgrind_control", "-i", "on", str(pid)], check=True, capture_output=True)
        cpu0, wall0 = _cpu_s(pid), time.monotonic()
        for k in range(args.cycles):
            cycle(args.warmup + k)
        clock.pose()                    # the last advance's physics has run
        cpu1, wall1 = _cpu_s(pid), time.monotonic()
        if args.callgrind:
            subprocess.run(["callgrind_control", "-d", "-i", "off", str(pid)], check=True, capture_output=True)
        wheels.disable()
    n = args.cycles
    clock_stats = emu.final_stats["clock"]
    physics_ms = 1e3 * clock_stats["cpu_s"] / clock_stats["steps"] * PERIOD_S / STEP_S
    user_ms, sys_ms = (1e3 * (b - a) / n for a, b in zip(cpu0, cpu1))
    print(f"{n} cycles, {args.emulator_config}: wall {1e3 * (wall1 - wall0) / n:.3f} ms/cycle, "
          f"emulator CPU {user_ms + sys_ms:.3f} ms/cycle (user {user_ms:.3f}, system {sys_ms:.3f}), "
          f"of which physics {physics_ms:.3f} (whole run), rest {user_ms + sys_ms - physics_ms:.3f}")
    if args.callgrind:
        outs = sorted(out_dir.glob(f"callgrind.out.{pid}*"), key=lambda p: p.stat().st_mtime)
        counted = [o for o in outs if _callgrind_instructions(o) > 0]
        # a profile naming another interpreter is not this run's emulator (seen while another
        # checkout's valgrind ran at the same time: it counted that checkout's code)
        foreign = [o for o in counted if not _profiled_command(o).startswith(sys.executable + " ")]
        if foreign or not counted:
            sys.exit(f"bench_emu_serve: the callgrind profile is not this run's emulator "
                     f"({', '.join(f'{o}: {_profiled_command(o)[:60]}' for o in foreign) or 'none counted'}); run again")
        total = sum(_callgrind_instructions(o) for o in counted)
        print(f"emulator instructions: {total / n:,.0f} per cycle ({', '.join(map(str, counted))})")


if __name__ == "__main__":
    main()
