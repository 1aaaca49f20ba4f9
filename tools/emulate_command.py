"""``swerve emulate``'s work: build the emulated bus, print its PORT line, serve until a stop signal.

The options and the PORT line's format are :mod:`swerve.tools.commands.emulate`; :func:`run`
takes the parsed command line.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading

from swerve.configs import locate_robot_file
from swerve.core.options import parse_ids
from swerve.driver.control_table import ID_MAX, table_for
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.body_settings import BodySettings, robot_on_bus
from swerve.emulator.clock import DEFAULT_REPLY_LATENCY_S
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import LinkSettings, freeze_startup_heap
from swerve.emulator.timing import Lockstep, scaled
from swerve.tools.commands.emulate import format_ids


def run(args: argparse.Namespace) -> int:
    if args.verbose:
        logging.basicConfig(level=logging.DEBUG, stream=sys.stderr)
    ids = parse_ids(args.ids, max_id=ID_MAX) if args.ids else None
    if args.frozen and (args.status_file or args.noise or args.emulator_config):
        raise ConfigError("--status-file, --noise and --emulator-config need physics (drop --frozen)")
    if args.physics and (ids is not None or args.model is not None):
        raise ConfigError("with --physics the IDs and model come from --config")
    if not args.lockstep and (args.control or args.reply_latency_us is not None):
        raise ConfigError("--control and --reply-latency-us need --lockstep")
    if args.lockstep and args.time_scale is not None:
        raise ConfigError("--time-scale and --lockstep exclude each other (the client paces a lockstep bus)")
    if args.lockstep:
        timing = Lockstep(args.control, DEFAULT_REPLY_LATENCY_S if args.reply_latency_us is None
                          else args.reply_latency_us * 1e-6)
    else:
        timing = scaled(1.0 if args.time_scale is None else args.time_scale)
    robot = load_robot_config(locate_robot_file(args.config).path)
    physics = None if args.frozen else load_config(resolve_emulator_config(args.emulator_config or "ideal"))
    table = table_for(args.model or robot.model)          # an unknown model fails here, named
    if physics is not None and table.model.lower() not in physics.gear_ratios:
        if args.physics or args.status_file or args.noise or args.live:
            raise ConfigError(f"{table.model} has no motor data in the emulator config (it covers "
                              f"{', '.join(sorted(physics.gear_ratios))}): it can be served register-only")
        print(f"{table.model}: no motor data (the emulator config covers {', '.join(sorted(physics.gear_ratios))}); "
              "serving its control table only, Present* items stay put", file=sys.stderr, flush=True)
        physics = None
    try:
        emu = build_emulator(robot, physics, ids=ids, model=args.model, baud=args.baud,
                             body=BodySettings() if args.physics or (physics is not None and robot_on_bus(robot, ids))
                             else None, timing=timing,
                             rate_hz=args.clock_hz, noise=args.noise, faults=args.faults,
                             status_file=args.status_file, adapter_latency_ms=args.adapter_latency_ms,
                             link=LinkSettings(path=args.link, wire_timing=args.wire_timing,
                                               baud_check=not args.no_baud_check))
    except ValueError as exc:            # ConfigError is a ValueError too
        raise exc if isinstance(exc, ConfigError) else ConfigError(str(exc)) from None
    stop = threading.Event()

    def _on_signal(signum, _frame):
        stop.set()

    if args.live and emu.world is None:
        raise ConfigError("--live streams the robot body's true pose: drop --frozen and emulate the "
                          "robot's servos")
    previous = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    stack = contextlib.ExitStack()
    try:
        try:
            emu.start()
        except OSError as exc:
            raise ConfigError(f"cannot open the pty or link: {exc.strerror or exc}") from None
        if args.live:
            from swerve.tools.live import LivePublisher, PosePump, parse_live

            live = stack.enter_context(LivePublisher(*parse_live(args.live), name="swerve emulator",
                                                      topics=("/true_pose",)))
            stack.callback(PosePump(live, lambda: emu.pose).start().close)
            print(f"LIVE {live.url}", file=sys.stderr, flush=True)
        freeze_startup_heap()
        ids_text = format_ids(s.id for s in emu.servos)
        control = f" CONTROL {emu.control.path}" if emu.control is not None else ""
        print(f"PORT {emu.port} BAUD {emu.baud} IDS {ids_text}{control}", flush=True)
        if emu.link_path:
            print(f"LINK {emu.link_path}", flush=True)
        what = "frozen (register-only)" if physics is None else (
            "moving the robot body" if emu.world is not None else "free shafts")
        adapter = "no USB adapter" if emu.adapter is None else f"USB adapter latency timer {emu.adapter.latency_ms} ms"
        print(f"{len(emu.servos)} x {emu.model} IDs {ids_text} at {emu.baud} bps, {what}, {adapter}",
              file=sys.stderr, flush=True)
        while not stop.wait(1.0):
            pass
    finally:
        stack.close()
        emu.close()
        for s, h in previous.items():
            signal.signal(s, h)
    if args.verbose:
        print(f"stats: {emu.stats.as_dict()}", file=sys.stderr)
    return 0
