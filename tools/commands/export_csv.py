"""``swerve export-csv LOG [--out FILE]``: one CSV row per control cycle."""
from __future__ import annotations

import argparse
from pathlib import Path

from swerve.tools.logs import read_log
from swerve.tools.logs.csv_export import export_csv


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", type=Path, help="run-log bag directory (or its .mcap file)")
    parser.add_argument("--out", metavar="FILE", type=Path, default=None,
                        help="CSV file to write (default: LOG.csv next to the log)")


def run(args: argparse.Namespace) -> int:
    log = read_log(args.log)
    log.warn_if_recovered(args.command)
    base = args.log.with_suffix("") if args.log.suffix == ".mcap" else args.log
    out = args.out or base.with_name(base.name + ".csv")
    export_csv(log, out)
    print(f"{out}: {len(log)} cycles")
    log.raise_if_damaged()      # what was intact is written; the damage still fails the command
    return 0
