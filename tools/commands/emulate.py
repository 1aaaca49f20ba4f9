"""``swerve emulate``: serve a bus of virtual X-series servos on a pty until SIGINT/SIGTERM.

The first line on stdout is ``PORT /dev/pts/N`` (then ``LINK path`` if ``--link`` was given);
open that path with the SDK, the driver or any serial tool at the servos' baud rate.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading

from swerve.configs.options import parse_ids
from swerve.driver.control_table import ID_MAX
from swerve.driver.errors import ConfigError

NAME = "emulate"
HELP = "serve emulated Dynamixel X servos on a pseudo-terminal (prints PORT /dev/pts/N)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None,
                        help="robot config (IDs, model and link baud from it), e.g. configs/robot.yaml")
    parser.add_argument("--ids", default=None, help="servo IDs, e.g. 1-8 or 1,2,5 (default: config or 1-8)")
    parser.add_argument("--model", default=None, help="servo model, e.g. xh430-w210 (default: config or xh430-w210)")
    parser.add_argument("--link", default=None, help="also create this symlink to the pty")
    parser.add_argument("--baud", type=int, default=None,
                        help="servos' initial baud rate in bps (default: config or 1000000)")
    parser.add_argument("--wire-timing", action="store_true",
                        help="pace replies at the baud rate as on a real cable")
    parser.add_argument("--faults", default=None,
                        help="fault injection, e.g. drop=0.05,corrupt=0.01,delay=0.002,vanish=3,"
                             "hwerror=5:overload,seed=1 (see emulator/README.md)")
    parser.add_argument("--time-scale", type=float, default=1.0,
                        help="simulated seconds per wall second (default 1)")
    parser.add_argument("--clock-hz", type=float, default=None,
                        help="servo clock rate, Hz (default 1000; with --physics: physics.rate_hz of "
                             "configs/emulator.yaml)")
    parser.add_argument("--physics", action="store_true",
                        help="servos move: Table 1 motors, firmware loops and the robot body of --config "
                             "(default configs/robot.yaml) with configs/emulator.yaml")
    parser.add_argument("--emulator-config", default=None, help="physics config (default configs/emulator.yaml)")
    parser.add_argument("--status-file", default=None,
                        help="with --physics: JSON file with the true pose, rewritten 20 times a second")
    parser.add_argument("--noise", default=None,
                        help="with --physics: sensor noise, e.g. position=0.5,current=0.002,seed=1")
    parser.add_argument("--no-baud-check", action="store_true",
                        help="answer whatever line speed the client sets")
    parser.add_argument("-v", "--verbose", action="store_true", help="log dispatch errors (debug)")


def run(args: argparse.Namespace) -> int:
    import logging

    from swerve.emulator import Emulator
    from swerve.emulator.server import freeze_startup_heap

    if args.verbose:
        logging.basicConfig(level=logging.DEBUG, stream=sys.stderr)
    ids = parse_ids(args.ids, max_id=ID_MAX) if args.ids else None
    if not args.physics and (args.status_file or args.noise or args.emulator_config):
        raise ConfigError("--status-file, --noise and --emulator-config need --physics")
    try:
        if args.physics:
            if ids is not None or args.model is not None:
                raise ConfigError("with --physics the IDs and model come from --config")
            from swerve.driver.control_table import CONFIG_DIR
            from swerve.emulator.robot_emulator import robot_emulator

            emu = robot_emulator(args.config or CONFIG_DIR / "robot.yaml",
                                 args.emulator_config or CONFIG_DIR / "emulator.yaml",
                                 time_scale=args.time_scale, status_file=args.status_file,
                                 noise=args.noise, faults=args.faults, link=args.link,
                                 wire_timing=args.wire_timing, baud=args.baud, rate_hz=args.clock_hz,
                                 baud_check=not args.no_baud_check)
        else:
            emu = Emulator(ids, args.model, args.baud, robot_config=args.config,
                           wire_timing=args.wire_timing, faults=args.faults, time_scale=args.time_scale,
                           clock_hz=args.clock_hz or 1000.0, link=args.link,
                           baud_check=not args.no_baud_check)
    except ValueError as exc:            # ConfigError is a ValueError too
        raise exc if isinstance(exc, ConfigError) else ConfigError(str(exc)) from None
    stop = threading.Event()

    def _on_signal(signum, _frame):
        stop.set()

    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            emu.start()
        except OSError as exc:
            raise ConfigError(f"cannot open the pty or link: {exc}") from None
        freeze_startup_heap()
        print(f"PORT {emu.port}", flush=True)
        if emu.link_path:
            print(f"LINK {emu.link_path}", flush=True)
        print(f"{len(emu.servos)} x {emu.model} IDs {','.join(str(s.id) for s in emu.servos)} "
              f"at {emu.baud} bps", file=sys.stderr, flush=True)
        while not stop.wait(1.0):
            pass
    finally:
        emu.close()
        for s, h in previous.items():
            signal.signal(s, h)
    if args.verbose:
        print(f"stats: {emu.stats.as_dict()}", file=sys.stderr)
    return 0
