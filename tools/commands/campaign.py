"""``swerve campaign``: many emulated robots, paths and faults in one command (docs/campaigns.md).

``campaign run FILE --out DIR``: every scenario of the campaign file (or a shipped campaign's
name: ``smoke``, ``tolerances``) as a lockstep run on the emulator, on a local process pool or
on Ray (``--ray auto|ADDRESS``); writes DIR/results.csv, summary.json, summary.md and plots,
resumes what DIR is missing when run again. ``campaign replay DIR INDEX``: one scenario again,
with its run log if asked, and its row compared with the one in results.csv. This module holds
the options; the work is :mod:`swerve.tools.campaign.command`, imported only once the command
line is valid.
"""
from __future__ import annotations

import argparse

from swerve.tools.argtypes import int_range


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    run = sub.add_parser("run", help="run (or resume) a campaign",
                         description="run every scenario of a campaign not in DIR yet")
    run.add_argument("file", metavar="FILE", help="campaign file, or a shipped campaign: smoke, tolerances")
    run.add_argument("--out", required=True, metavar="DIR", help="results folder (created; reused to resume)")
    run.add_argument("--workers", type=int_range(1, 4096), default=None,
                     help="scenarios at a time (pool: default the CPUs; --ray auto: the local Ray's CPUs)")
    run.add_argument("--ray", default=None, metavar="auto|ADDRESS",
                     help='run on Ray: "auto" starts a local Ray, HOST:PORT joins a running cluster '
                          '(needs pip install "swerve[cluster]")')
    run.add_argument("--samples", type=int_range(1, 10**6), default=None,
                     help="robots to draw instead of the file's samples (a quick look; same draws)")
    run.add_argument("--no-plots", action="store_true", help="skip the plots")
    replay = sub.add_parser("replay", help="run one scenario of a campaign again",
                            description="run scenario INDEX of the campaign in DIR again, in this process")
    replay.add_argument("dir", metavar="DIR", help="the campaign's results folder")
    replay.add_argument("index", metavar="INDEX", type=int_range(0), help="scenario index (results.csv column index)")
    replay.add_argument("--log", default=None, metavar="DIR", help="write the run log (ROS 2 bag, MCAP) here")
