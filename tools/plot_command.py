"""``swerve plot``'s work: read the run log (and a simulation log) and write its figures.

The options are :mod:`swerve.tools.commands.plot`; :func:`run` takes the parsed command line.
"""
from __future__ import annotations

import argparse

from swerve.core.atomic import files_into
from swerve.tools.logs import read_log
from swerve.tools.logs.log_figures import plot_run


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
