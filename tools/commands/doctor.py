"""``swerve doctor``: a checklist of the servo bus against the robot file, pass / warn / fail.

Exit status: 0 when every check passes or only warns, 1 when a check fails, 2 for bad input (as
every command). Settings ``swerve run`` writes itself before it moves (operating mode, Return
Delay Time) pass, with what run will set. With ``--emulate`` the bus is an emulated robot started
here (register-only), its replies paced as on the cable and through its USB adapter, whose
latency timer is checked as a ttyUSB's is on the robot.

This module holds the options; the work is :mod:`swerve.tools.doctor.command`, imported only
once the command line is valid.
"""
from __future__ import annotations

import argparse

from swerve.tools.argtypes import finite_float, int_range
from swerve.tools.cli import add_adapter_option, add_bus_options


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
