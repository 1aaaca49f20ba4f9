"""``swerve emulate``: serve a bus of virtual X-series servos on a pty until SIGINT/SIGTERM.

The first line on stdout is ``PORT /dev/pts/N BAUD 1000000 IDS 1-8`` (then ``LINK path`` if
``--link`` was given); open that path with the SDK, the driver or any serial tool at that baud rate.
Every servo runs its motor and firmware loops (a free shaft); when the robot file's servos are all
on the bus, they also move the robot body. ``--frozen`` serves a register-only bus.

``--lockstep``: robot time advances only when a client asks through the control socket named at
the end of the PORT line (``... IDS 1-8 CONTROL /tmp/.../control.sock``; protocol in
emulator/README.md); a bus nobody drives stays paused.
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
from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP, resolve_emulator_config
from swerve.emulator.body_settings import BodySettings, robot_on_bus
from swerve.emulator.clock import DEFAULT_REPLY_LATENCY_S
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import LinkSettings, freeze_startup_heap
from swerve.emulator.timing import Lockstep, scaled
from swerve.tools.argtypes import baud_rate, finite_float
from swerve.tools.cli import add_adapter_option


def format_ids(ids) -> str:
    """``[1, 2, 3, 5]`` -> ``"1-3,5"`` (the inverse of :func:`parse_ids` for sorted distinct IDs)."""
    runs: list[list[int]] = []
    for i in sorted(ids):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def parse_port_line(line: str) -> tuple[str, int, list[int]]:
    """``"PORT /dev/pts/3 BAUD 1000000 IDS 1-8"`` -> ``("/dev/pts/3", 1000000, [1, ..., 8])``
    (a trailing ``CONTROL path`` is allowed: :func:`parse_control`)."""
    words = line.split()
    if len(words) == 8 and words[6] == "CONTROL":
        words = words[:6]
    if len(words) != 6 or words[0] != "PORT" or words[2] != "BAUD" or words[4] != "IDS":
        raise ConfigError(f"not a PORT line: {line.strip()!r}")
    try:
        baud = int(words[3])
    except ValueError:
        raise ConfigError(f"PORT line: bad baud {words[3]!r}") from None
    return words[1], baud, parse_ids(words[5], "IDS", max_id=ID_MAX)


def parse_control(line: str) -> str | None:
    """The lockstep control socket named on a PORT line, or None (a wall-clock bus)."""
    parse_port_line(line)
    words = line.split()
    return words[7] if len(words) == 8 else None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None,
                        help="robot config (IDs, model and link baud from it), e.g. configs/robot.yaml")
    parser.add_argument("--ids", default=None, help="servo IDs, e.g. 1-8 or 1,2,5 (default: config or 1-8)")
    parser.add_argument("--model", default=None, help="servo model, e.g. xh430-w210 (default: config or xh430-w210)")
    parser.add_argument("--link", default=None, help="also create this symlink to the pty")
    parser.add_argument("--baud", type=baud_rate, default=None,
                        help="servos' initial baud rate in bps (default: config or 1000000)")
    parser.add_argument("--wire-timing", action="store_true",
                        help="pace replies at the baud rate as on a real cable (and through the USB adapter)")
    add_adapter_option(parser)
    parser.add_argument("--faults", default=None,
                        help="fault injection, e.g. drop=0.05,corrupt=0.01,delay=0.002,vanish=3,"
                             "hwerror=5:overload,seed=1 (see emulator/README.md)")
    parser.add_argument("--time-scale", type=finite_float(0.0, 1000.0), default=None,
                        help="simulated seconds per wall second (default 1; not with --lockstep)")
    parser.add_argument("--lockstep", action="store_true",
                        help="simulated time advances only on request through a control socket "
                             "(its path ends the PORT line; see emulator/README.md)")
    parser.add_argument("--control", default=None,
                        help="with --lockstep: path of the control socket (default: a temporary one)")
    parser.add_argument("--reply-latency-us", type=finite_float(0.0, 1e6), default=None,
                        help="with --lockstep: each servo's reply latency on top of its Return Delay, "
                             "us (default 50)")
    parser.add_argument("--clock-hz", type=finite_float(1.0, 100_000.0), default=None,
                        help="clock rate, Hz (default: physics.rate_hz of configs/emulator.yaml; "
                             "--frozen: 1000)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--physics", action="store_true",
                      help="require the robot body: the servos of --config, moving one robot "
                           "(default: added when the robot's servos are all on the bus)")
    mode.add_argument("--frozen", action="store_true",
                      help="register-only bus: Present* items stay put (protocol tests)")
    parser.add_argument("--emulator-config", default=None, help=EMULATOR_CONFIG_HELP + "; default ideal")
    parser.add_argument("--status-file", default=None,
                        help="with the robot body: JSON file with the true pose, rewritten 20 times a second")
    parser.add_argument("--noise", default=None,
                        help="sensor noise, e.g. position=0.5,current=0.002,seed=1")
    parser.add_argument("--live", default=None, metavar="[HOST:]PORT",
                        help="with the robot body: stream the true pose (/true_pose) over the Foxglove "
                             "WebSocket protocol on PORT (127.0.0.1 unless HOST is given)")
    parser.add_argument("--no-baud-check", action="store_true",
                        help="answer whatever line speed the client sets")
    parser.add_argument("-v", "--verbose", action="store_true", help="log dispatch errors (debug)")


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
