"""``swerve emulate``: serve a bus of virtual X-series servos on a pty until SIGINT/SIGTERM.

The first line on stdout is ``PORT /dev/pts/N BAUD 1000000 IDS 1-8`` (then ``LINK path`` if
``--link`` was given); open that path with the SDK, the driver or any serial tool at that baud rate.
Every servo runs its motor and firmware loops (a free shaft); when the robot file's servos are all
on the bus, they also move the robot body. ``--frozen`` serves a register-only bus.

``--lockstep``: robot time advances only when a client asks through the control socket named at
the end of the PORT line (``... IDS 1-8 CONTROL /tmp/.../control.sock``; protocol in
emulator/README.md); a bus nobody drives stays paused.

This module holds the options and the PORT line's format; the work is
:mod:`swerve.tools.emulate_command`, imported only once the command line is valid.
"""
from __future__ import annotations

import argparse

from swerve.core.options import parse_ids
from swerve.driver.control_table import ID_MAX
from swerve.driver.errors import ConfigError
from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
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
