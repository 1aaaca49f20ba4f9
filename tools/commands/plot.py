"""``swerve plot LOG --out DIR``: PNG figures like the paper's Figs 11-16.

The figures are drawn into a temporary folder beside ``DIR`` and moved into it only when all of
them are written, so a failure (a full disk) leaves ``DIR`` as it was. This module holds the
options; the work is :mod:`swerve.tools.plot_command`, imported only once the command line is
valid.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", type=Path, help="run-log bag directory (or its .mcap file)")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True, help="directory for the PNG files")
    parser.add_argument("--sim", metavar="SIMLOG", type=Path, default=None,
                        help="a second run log (e.g. from `swerve sim`) overlaid as simulation")
