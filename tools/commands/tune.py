"""``swerve tune``'s options: identify one servo's DC motor from step experiments and design its
loop gains.

Runs on a real bus (``--port``) or on an in-process emulator on a pty (``--emulate``) through the
same driver code path. Drive servos get the velocity PI tuned, steering servos the position P.
Results: ``OUT/tune_<id>.json|.yaml``, ``OUT/pwm_<id>.png``, ``OUT/step_<id>.png``. The gains stay
in the servo's RAM; ``--write-config`` also stores them in the robot config. The work is
:mod:`swerve.tools.tune.command`, imported only once the command line is valid.
"""
from __future__ import annotations

import argparse
import math

from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import baud_rate, finite_float, int_range, positive_float, servo_id
from swerve.tools.cli import add_config_option


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="serial port of the bus (e.g. /dev/ttyUSB0)")
    where.add_argument("--emulate", action="store_true", help="tune an emulated servo (in-process, on a pty)")
    parser.add_argument("--baud", type=baud_rate, default=None, help="bps (default: robot config link.baud)")
    parser.add_argument("--id", type=servo_id, default=1, help="servo ID (default 1)")
    parser.add_argument("--mode", choices=("drive", "steering"), default=None,
                        help="which loop to tune (default: from the ID's role in the robot config)")
    parser.add_argument("--overshoot-max", type=finite_float(0.0, 1.0), default=0.02,
                        help="velocity step overshoot limit, fraction (default 0.02)")
    parser.add_argument("--settle-max", type=finite_float(0.0, lo_open=True, allow_inf=True), default=math.inf,
                        help="2 %% settle-time limit of the tuned step, s (default: none, fastest)")
    parser.add_argument("--velocity-step", type=positive_float, default=None,
                        help="velocity step, rad/s at the output (default 100 units = 2.40 rad/s)")
    parser.add_argument("--position-step", type=positive_float, default=None,
                        help="position step, rad (default 512 pulses = 0.785 rad)")
    parser.add_argument("--pwm", type=finite_float(0.0, 1.0, lo_open=True), default=0.5, help="largest open-loop PWM duty, 0..1 (default 0.5)")
    parser.add_argument("--current-max", type=positive_float, default=None,
                        help="abort above this |Present Current|, A (default: the servo's Current Limit)")
    add_config_option(parser)
    parser.add_argument("--prior", default=None,
                        help="motor parameters to start from and to fix L, Km (paper Table 1; a profile "
                             "name or a physics .yaml; default: the shipped emulator.yaml)")
    parser.add_argument("--emulator-config", default=None,
                        help="--emulate: " + EMULATOR_CONFIG_HELP.replace("%", "%%")
                             + " (e.g. a copy with +30 %% inertia)")
    parser.add_argument("--emulator", choices=("servo", "robot"), default="servo",
                        help="--emulate: 'servo' = each servo alone, unloaded, 1 kHz physics (default); "
                             "'robot' = the project's robot emulator (2 kHz physics, robot mass on the "
                             "drive shafts as in configs/emulator.yaml body.load_enabled)")
    parser.add_argument("--noise", action="store_true",
                        help="--emulate: sensor noise on (0.5 pulse encoder, 4 mA current, std)")
    parser.add_argument("--seed", type=int_range(0, 2**32 - 1), default=0,
                        help="--emulate: noise seed (default 0: the same noise every run)")
    parser.add_argument("--write-config", action="store_true",
                        help="store the gains in the robot file (drive.gains or steering.gains)")
    parser.add_argument("--out", default="out/tune", help="directory for PNG/JSON/YAML results")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true",
                        help="print the identified parameters, designed gains and step metrics as JSON")
