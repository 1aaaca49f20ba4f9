"""``swerve doctor``: a checklist of the servo bus against the robot file, pass / warn / fail.

Exit status: 0 when every check passes or only warns, 1 when a check fails, 2 for bad input (as
every command). Settings ``swerve run`` writes itself before it moves (operating mode, Return
Delay Time) pass, with what run will set. With ``--emulate`` the bus is an emulated robot started
here (register-only), its replies paced as on the cable and through its USB adapter, whose
latency timer is checked as a ttyUSB's is on the robot.
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
from swerve.tools.argtypes import finite_float, int_range
from swerve.tools.cli import add_adapter_option, add_bus_options
from swerve.tools.doctor import EmulatedLatencyTimer, diagnose


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_options(parser, "check an emulated bus of the robot file's servos (started here)")
    parser.add_argument("--fix", action="store_true",
                        help="repair what can be repaired: move servos to the file's ID and baud, reboot "
                             "servos with a latched hardware error, write modes/return delay/gains, set "
                             "the latency timer (needs write access to sysfs)")
    parser.add_argument("--cycles", type=int_range(1, 1_000_000), default=200, help="timed read/write cycles (default 200)")
    parser.add_argument("--timeout-margin-ms", type=finite_float(0.0, 10_000.0), default=None,
                        help="slack on every reply deadline (default 2 ms; 50 ms with --emulate)")
    add_adapter_option(parser)
    parser.add_argument("--json", action="store_true", help="print the report as JSON")


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
