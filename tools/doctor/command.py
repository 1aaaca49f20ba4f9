"""``swerve doctor``'s work: start the emulated bus if asked, run the checklist, print the report.

The options are :mod:`swerve.tools.commands.doctor`; :func:`run` takes the parsed command line
and returns the exit status of the report.
"""
from __future__ import annotations

import argparse
import contextlib
import json

from swerve.configs import locate_robot_file
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import LinkSettings
from swerve.tools.doctor import EmulatedLatencyTimer, diagnose


def run(args: argparse.Namespace) -> int:
    if args.adapter_latency_ms is not None and not args.emulate:
        raise ConfigError("--adapter-latency-ms needs --emulate (on the robot, doctor reads the adapter's own)")
    cfg = load_robot_config(locate_robot_file(args.config).path)
    margin_ms = args.timeout_margin_ms if args.timeout_margin_ms is not None else (50.0 if args.emulate else 2.0)
    latency = None
    with contextlib.ExitStack() as stack:
        if args.emulate:
            emu = stack.enter_context(build_emulator(cfg, link=LinkSettings(wire_timing=True),  # register-only
                                                     adapter_latency_ms=args.adapter_latency_ms))
            port = emu.port
            latency = EmulatedLatencyTimer(emu.adapter)
            if args.timeout_margin_ms is None and emu.adapter is not None:
                # a ttyUSB's deadlines count the latency timer twice (driver.transport); a pty has none
                margin_ms += 2 * emu.adapter.latency_ms
        else:
            port = args.port or cfg.link.port
        report = diagnose(cfg, port, fix=args.fix, margin_s=margin_ms * 1e-3, cycles=args.cycles, latency=latency)
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        for c in report.checks:
            print(c.line())
        for f in report.fixed:
            print(f"fixed: {f}")
        print(report.verdict())
    return report.exit_code
