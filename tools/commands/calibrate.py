"""``swerve calibrate``: steering zero, direction signs and wheel radius, on the robot or emulator.

Without ``--write`` it prints the calibrated keys as YAML to paste; with ``--write`` it edits the
robot file in place (comments kept, validated, replaced atomically). This module holds the
options; the work is :mod:`swerve.tools.calibrate_command`, imported only once the command line
is valid.
"""
from __future__ import annotations

import argparse

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
