"""``swerve plot LOG --out DIR``: PNG figures like the paper's Figs 11-16.

The figures are drawn into a temporary folder beside ``DIR`` and moved into it only when all of
them are written, so a failure (a full disk) leaves ``DIR`` as it was.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from swerve.core.atomic import files_into
from swerve.tools.logs import read_log
from swerve.tools.logs.log_figures import plot_run


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", type=Path, help="run-log bag directory (or its .mcap file)")
    parser.add_argument("--out", metavar="DIR", type=Path, required=True, help="directory for the PNG files")
    parser.add_argument("--sim", metavar="SIMLOG", type=Path, default=None,
                        help="a second run log (e.g. from `swerve sim`) overlaid as simulation")


def run(args: argparse.Namespace) -> int:
    log = read_log(args.log)
    log.warn_if_recovered(args.command)
    sim = read_log(args.sim) if args.sim is not None else None
    with files_into(args.out) as tmp:       # all figures or none: no partial folder on a full disk
        written = plot_run(log, tmp, sim=sim)
    for path in written:
        print(args.out / path.name)
    for read in (log, sim):
        if read is not None:
            read.raise_if_damaged()
    return 0
