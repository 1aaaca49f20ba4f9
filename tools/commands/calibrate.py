"""``swerve calibrate``: steering zero, direction signs and wheel radius, on the robot or emulator.

Without ``--write`` it prints the calibrated keys as YAML to paste; with ``--write`` it edits the
robot file in place (comments kept, validated, replaced atomically).
"""
from __future__ import annotations

import argparse

from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import finite_float
from swerve.tools.cli import add_bus_options

NAME = "calibrate"
HELP = "measure steering zero, wheel direction signs and wheel radius; print or --write them"

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
                        help=f"with --emulate: {EMULATOR_CONFIG_HELP}; default ideal")
    parser.add_argument("--time-scale", type=finite_float(0.0, 1000.0, lo_open=True), default=1.0,
                        help="with --emulate: robot seconds per wall second (default 1)")
    parser.add_argument("--lockstep", action="store_true",
                        help="with --emulate: the emulator owns robot time (repeatable results, as fast "
                             "as the host allows; --time-scale is then unused)")
    parser.add_argument("--timeout-margin-ms", type=finite_float(0.0, 10_000.0), default=None,
                        help="slack on every reply deadline (default 2 ms; 50 ms with --emulate)")


def run(args: argparse.Namespace) -> int:
    import contextlib
    import sys

    from swerve.driver.bus import Bus
    from swerve.driver.errors import ConfigError
    from swerve.configs import locate_robot_file
    from swerve.driver.robot_config import load_robot_config
    from swerve.tools import calibrate as cal

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

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepClock

    margin_ms = args.timeout_margin_ms if args.timeout_margin_ms is not None else (
        LOCKSTEP_TIMEOUT_MARGIN_S * 1e3 if args.lockstep else 50.0 if args.emulate else 2.0)
    values: dict = {}
    with contextlib.ExitStack() as stack:
        clock = None
        if args.emulate:
            from swerve.emulator.robot_emulator import robot_emulator

            from swerve.emulator.physics.profiles import resolve_emulator_config

            physics = resolve_emulator_config(args.emulator_config or "ideal")
            emu = stack.enter_context(robot_emulator(args.emulated_robot or cfg_path, physics, body=True,
                                                     time_scale=args.time_scale, rate_hz=1000.0,
                                                     lockstep=args.lockstep))
            port = emu.port
            if args.lockstep:       # connected before anything is written to the pty
                clock = stack.enter_context(LockstepClock(emu.control.path))
        else:
            port = args.port or cfg.link.port
        bus = stack.enter_context(Bus(port, cfg.link.baud, default_model=cfg.model, retries=1,
                                      timeout_margin_s=margin_ms * 1e-3))
        if clock is not None:
            clock.attach(bus)
        session = stack.enter_context(cal.Session(bus, cfg, time_scale=args.time_scale, log=log, clock=clock))
        scale = cfg.table["present_position"].scale
        if args.emulate and args.yes:
            from swerve.emulator.robot_emulator import status

            def true_state() -> dict:
                if clock is not None:
                    clock.pose()    # answered once the emulator has run the physics up to robot time
                with emu.lock:
                    return status(emu)

            op = cal.EmulatorOperator(true_state, rad_per_pulse=scale, settle=session.sleep)
        elif args.yes:
            op = cal.DefaultOperator()
        else:
            op = cal.ConsoleOperator(cfg.wheels)
        if "steering" in args.steps:
            values["center_pulse"] = cal.steering_zero(session, op, jog=args.jog or args.emulate)
            session.use(cal.with_calibration(session.cfg, center_pulse=values["center_pulse"]))
            log(f"steering centres: {values['center_pulse']} pulse (were "
                f"{[w.center_pulse for w in cfg.wheels]})")
        if "directions" in args.steps:
            values["drive_direction"], values["steer_direction"] = cal.directions(session, op)
            session.use(cal.with_calibration(session.cfg, drive_direction=values["drive_direction"],
                                             steer_direction=values["steer_direction"]))
        if "radius" in args.steps:
            radius, facts = cal.wheel_radius(session, op, distance_m=args.distance, speed_mps=args.speed)
            values["wheel_radius_m"] = radius
            log(f"wheel radius: {radius * 1e3:.3f} mm (was {cfg.wheel_radius_m * 1e3:.3f} mm; encoders "
                f"{facts['encoder_distance_m']:.4f} m, measured {facts['measured_distance_m']:.4f} m)")
    if args.write:
        cal.write_robot_file(cfg_path, **values)
        log(f"wrote {cfg_path}")
    else:
        print(cal.yaml_snippet(**values), end="")
    return 0
