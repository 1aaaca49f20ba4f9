"""``swerve run``: the 62.5 Hz tracking loop on the robot (``--port``) or the emulator (``--emulate``).

Prints which robot file it uses (``--config``, ``$SWERVE_CONFIG``, ``~/.config/swerve/robot.yaml``
or the shipped one) on its first line. Sets operating modes and gains from that file, arms the Bus Watchdog, steers to the
start angles, runs the trajectory, stops, and prints the tracking summary (the keys of
``swerve sim --json`` plus loop timing). Ctrl-C, an exception, a missing servo or a hardware
error stop the wheels and turn the torque off; the log stays readable.

``--emulate --lockstep``: the emulator owns robot time (it advances only when the loop has
finished a cycle, and each bus exchange costs its wire time), so the run is the same on an idle
or a loaded machine and the log is byte-for-byte repeatable; as fast as the host allows, or
paced at ``--time-scale S``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from swerve.core.errors import ConfigError
from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import finite_float
from swerve.tools.cli import add_adapter_option, add_config_option, add_trajectory_option
from swerve.tools.commands.sim import parse_x0
from swerve.tools.run.orchestrate import RunRequest, run_tracking


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_trajectory_option(parser)
    parser.add_argument("--gains", default=None,
                        help="gain schedule .npz/.dat from `swerve synth` (default: synthesise with Riccati)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--port", default=None, help="serial port of the U2D2 (default: link.port in the config)")
    where.add_argument("--emulate", action="store_true", help="start the servo emulator on a pty and drive it")
    add_config_option(parser)
    parser.add_argument("--lockstep", action="store_true",
                        help="with --emulate: robot time owned by the emulator (repeatable runs, "
                             "as fast as possible unless --time-scale is given)")
    parser.add_argument("--time-scale", type=finite_float(0.0, 1000.0, lo_open=True), default=None,
                        help="robot seconds per wall second: only for an emulator (--emulate, or --port "
                             "on a `swerve emulate --time-scale S` pty); default 1 (--lockstep: unpaced)")
    parser.add_argument("--timeout-margin-ms", type=finite_float(0.0, 10_000.0), default=None,
                        help="slack on every bus reply deadline (default: 2 ms; 50 ms with --emulate)")
    parser.add_argument("--log", default=None,
                        help="run log (ROS 2 bag directory, MCAP); default out/runs/<trajectory>-<time>")
    parser.add_argument("--no-log", action="store_true", help="do not write a run log")
    parser.add_argument("--fast-read", action="store_true", help="use Fast Sync Read (firmware >= 45)")
    parser.add_argument("--faults", default=None,
                        help="with --emulate: fault injection, e.g. drop=0.02 (see emulator/README.md)")
    parser.add_argument("--emulator-config", default=None, help=f"with --emulate: {EMULATOR_CONFIG_HELP}; default ideal")
    add_adapter_option(parser)
    parser.add_argument("--x0", metavar="x,y,θ,δ1,δ2",
                        help="the robot's start state in m and rad (default: the trajectory's)")
    parser.add_argument("--on-servo-fault", choices=("stop", "recover"), default="stop",
                        help="on a servo's hardware error: stop the robot (default), or recover: stop, "
                             "reboot the servo, restore its settings from the robot file, re-home the "
                             "steering and resume (at most 3 times a minute)")
    parser.add_argument("--live", default=None, metavar="[HOST:]PORT",
                        help="stream the run log's topics live over the Foxglove WebSocket protocol "
                             "(127.0.0.1 unless HOST is given; e.g. 8765 or 0.0.0.0:8765)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace) -> int:
    if args.lockstep and not args.emulate:
        raise ConfigError("--lockstep needs --emulate (a real bus, or --port, runs on the wall clock)")
    if args.time_scale is None and not args.lockstep:
        args.time_scale = 1.0
    if args.time_scale is not None and not args.time_scale > 0:
        raise ConfigError(f"--time-scale must be positive, got {args.time_scale}")
    if args.emulator_config is not None and not args.emulate:
        raise ConfigError("--emulator-config needs --emulate")
    if args.adapter_latency_ms is not None and not args.emulate:
        raise ConfigError("--adapter-latency-ms needs --emulate (on the robot, doctor reads and sets the real one)")
    log = None if args.no_log else (
        Path(args.log) if args.log else
        Path("out/runs") / f"{Path(args.trajectory).stem}-{time.strftime('%Y%m%d-%H%M%S')}")
    req = RunRequest(trajectory=args.trajectory, gains=args.gains, config=args.config,
                     port=args.port, emulate=args.emulate, lockstep=args.lockstep,
                     time_scale=args.time_scale, log=log,
                     fast_read=args.fast_read, faults=args.faults, emulator_config=args.emulator_config,
                     adapter_latency_ms=args.adapter_latency_ms,
                     timeout_margin_s=None if args.timeout_margin_ms is None else args.timeout_margin_ms / 1e3,
                     progress=sys.stderr.isatty(), on_servo_fault=args.on_servo_fault, live=args.live,
                     start=None if args.x0 is None else tuple(parse_x0(args.x0)))
    out = sys.stderr if args.json else sys.stdout
    result = run_tracking(req, on_config=lambda c: print(f"config: {c.describe()}", file=out, flush=True))
    s = result.summary.to_dict()
    if args.json:
        print(result.summary.to_json())
    else:
        width = max(map(len, s))
        for key in sorted(s):
            val = s[key]
            print(f"{key:<{width}}  {val:.6g}" if isinstance(val, float) else f"{key:<{width}}  {val}")
        if log is not None:
            print(f"log: {log}", file=sys.stderr)
    if result.aborted is not None:
        raise result.aborted
    return 0
