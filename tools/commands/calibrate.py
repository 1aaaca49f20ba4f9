"""``swerve calibrate``: steering zero, direction signs and wheel radius, on the robot or emulator.

Without ``--write`` it prints the calibrated keys as YAML to paste; with ``--write`` it edits the
robot file in place (comments kept, validated, replaced atomically).
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
from swerve.tools.argtypes import finite_float
from swerve.tools.cli import add_bus_options


STEPS = ("steering", "directions", "radius")


def _steps(text: str) -> tuple[str, ...]:
    steps = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in steps if s not in STEPS]
    if bad or not steps:
        raise argparse.ArgumentTypeError(f"--steps {text!r}: choose from {','.join(STEPS)}")
    return steps


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_bus_options(parser, "calibrate the emulated robot (started here); see --emulated-robot")
    parser.add_argument("--write", action="store_true",
                        help="edit the robot file in place (comments kept; validated; atomic replace)")
    parser.add_argument("--yes", action="store_true",
                        help="answer every prompt with its default. On the emulator the answers come from "
                             "its true state instead (which wheel angle is straight, which way a wheel "
                             "turned, the distance travelled), as a person would see them")
    parser.add_argument("--jog", action="store_true",
                        help="steering zero with the torque on, jogging each wheel with the arrow keys "
                             "(default: torque off, set by hand); always on with --emulate")
    parser.add_argument("--steps", type=_steps, default=STEPS, metavar="LIST",
                        help="which steps, comma-separated (default steering,directions,radius)")
    parser.add_argument("--distance", type=finite_float(0.0, 100.0, lo_open=True), default=1.0,
                        help="radius step: distance to drive straight, m (default 1.0); leave room")
    parser.add_argument("--speed", type=finite_float(0.0, 10.0, lo_open=True), default=0.1, help="radius step: ground speed, m/s (default 0.1)")
    parser.add_argument("--emulated-robot", default=None,
                        help="with --emulate: the robot file the emulator is built from; its steering "
                             "centres, direction signs and wheel radius are the truth that calibration "
                             "must find (default: --config)")
    parser.add_argument("--emulator-config", default=None,
                        help="with --emulate: the emulated robot's physics, a profile (ideal, realistic) or a "
                             "file; its wheel radius scales and steering offsets are part of the truth "
                             "(default ideal)")
    parser.add_argument("--time-scale", type=finite_float(0.0, 1000.0, lo_open=True), default=1.0,
                        help="with --emulate: robot seconds per wall second (default 1)")
    parser.add_argument("--lockstep", action="store_true",
                        help="with --emulate: the emulator owns robot time (repeatable results, as fast "
                             "as the host allows; --time-scale is then unused)")
    parser.add_argument("--timeout-margin-ms", type=finite_float(0.0, 10_000.0), default=None,
                        help="slack on every reply deadline (default 2 ms; 50 ms with --emulate)")


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
