"""``swerve calibrate``'s work: open the bus (or start the emulated robot), run the steps, print or
write the calibrated keys.

The options are :mod:`swerve.tools.commands.calibrate`; :func:`run` takes the parsed command line.
"""
from __future__ import annotations

import argparse
import contextlib
import sys

from swerve.configs import locate_robot_file
from swerve.core.atomic import check_writable
from swerve.driver.bus import Bus
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import load_robot_config
from swerve.tools import calibrate as cal
from swerve.tools.calibrate_emulated import emulated_bus, emulator_operator


def run(args: argparse.Namespace) -> int:
    if not args.time_scale > 0 or (args.time_scale != 1.0 and not args.emulate):
        raise ConfigError("--time-scale must be positive and needs --emulate")
    if args.lockstep and not args.emulate:
        raise ConfigError("--lockstep needs --emulate: a real bus runs on the wall clock")
    if args.emulated_robot and not args.emulate:
        raise ConfigError("--emulated-robot needs --emulate")
    if args.emulator_config and not args.emulate:
        raise ConfigError("--emulator-config needs --emulate")
    choice = locate_robot_file(args.config)
    cfg_path = choice.path
    cfg = load_robot_config(cfg_path)
    if args.write and choice.source == "shipped":
        raise ConfigError(f"--write will not edit the shipped robot file {cfg_path}: copy it, then pass "
                          "--config FILE (or set $SWERVE_CONFIG)")
    if args.write:          # a read-only file, folder or mount is refused before the robot moves
        check_writable(cfg_path, mkdir=False)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    margin_s = None if args.timeout_margin_ms is None else args.timeout_margin_ms * 1e-3
    steps = dict(jog=args.jog or args.emulate, distance_m=args.distance, speed_mps=args.speed)
    with contextlib.ExitStack() as stack:
        if args.emulate:
            bus, clock, emu = stack.enter_context(emulated_bus(
                args.emulated_robot or cfg_path, cfg, emulator_config=args.emulator_config, lockstep=args.lockstep,
                time_scale=args.time_scale, margin_s=margin_s))
        else:
            clock = None
            bus = stack.enter_context(Bus(args.port or cfg.link.port, cfg.link.baud, default_model=cfg.model,
                                          retries=1, timeout_margin_s=2e-3 if margin_s is None else margin_s))
        session = stack.enter_context(cal.Session(bus, cfg, time_scale=args.time_scale, log=log, clock=clock))
        if args.emulate and args.yes:
            op = emulator_operator(emu, clock, cfg, session.sleep)
        elif args.yes:
            op = cal.DefaultOperator()
        else:
            op = cal.ConsoleOperator(cfg.wheels)
        values = cal.run_steps(session, op, args.steps, **steps)
    values.pop("radius_facts", None)
    if args.write:
        cal.write_robot_file(cfg_path, **values)
        log(f"wrote {cfg_path}")
    else:
        print(cal.yaml_snippet(**values), end="")
    return 0
