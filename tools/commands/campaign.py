"""``swerve campaign``: many emulated robots, paths and faults in one command (docs/campaigns.md).

``campaign run FILE --out DIR``: every scenario of the campaign file (or a shipped campaign's
name: ``smoke``, ``tolerances``) as a lockstep run on the emulator, on a local process pool or
on Ray (``--ray auto|ADDRESS``); writes DIR/results.csv, summary.json, summary.md and plots,
resumes what DIR is missing when run again. ``campaign replay DIR INDEX``: one scenario again,
with its run log if asked, and its row compared with the one in results.csv.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swerve.core.errors import ConfigError
from swerve.tools.argtypes import int_range
from swerve.tools.campaign.engines import make_engine, require_ray
from swerve.tools.campaign.report import table, write_summary
from swerve.tools.campaign.runner import run_missing
from swerve.tools.campaign.scenario import run_scenario
from swerve.tools.campaign.spec import load_campaign
from swerve.tools.campaign.store import Store, load_folder, read_results


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


def run(args: argparse.Namespace) -> int:
    return _run(args) if args.action == "run" else _replay(args)


def _run(args: argparse.Namespace) -> int:
    # matplotlib, only when the plots are drawn
    from swerve.tools.campaign.figures import plot_campaign

    campaign = load_campaign(args.file)
    if args.samples is not None:
        campaign = campaign.with_samples(args.samples)
    if args.ray is not None and not args.ray.strip():
        raise ConfigError('--ray needs "auto" or the ADDRESS (HOST:PORT) of a running cluster')
    # Ray is joined before the results folder is made: an address that cannot be reached
    # leaves nothing behind
    if args.ray is not None:
        require_ray()
    ray_engine = make_engine(campaign, workers=args.workers, ray=args.ray) if args.ray is not None else None
    out = Path(args.out)
    try:
        store = Store.open(out, campaign)
    except BaseException:
        if ray_engine is not None:
            ray_engine.close()
        raise
    missing = len(store.missing())
    print(f"campaign {campaign.name}: {campaign.scenarios} scenarios ({campaign.samples} robots x "
          f"{len(campaign.cells)} grid cells), {campaign.scenarios - missing} already in {out}", flush=True)
    stats = None
    if missing:
        engine = ray_engine or make_engine(campaign, workers=args.workers, ray=None)
        stats = run_missing(store, engine, progress=sys.stderr.isatty())
    else:
        if ray_engine is not None:
            ray_engine.close()
        store.write_results()
    rows = store.rows()
    summary = write_summary(campaign, rows, out)
    if not args.no_plots:
        plot_campaign(campaign, rows, out)
    print(table(summary))
    print("\nworst scenarios (replay one with the command shown):")
    for w in summary["worst"][:5]:
        print(f"  {w['index']:>6}  {w['status']:<9} {w['trajectory']}  {w['replay']}")
    if stats is not None:
        print(f"\n{stats.ran} scenarios in {stats.wall_s:.1f} s ({stats.slots} at a time; {stats.busy_s:.1f} s "
              f"of scenario time)", file=sys.stderr)
    print(f"results: {out / 'results.csv'}\nsummary: {out / 'summary.md'}")
    return 0


def _replay(args: argparse.Namespace) -> int:
    campaign = load_folder(args.dir)
    cells = len(campaign.cells)
    if args.index // cells + 1 > campaign.samples:
        campaign = campaign.with_samples(args.index // cells + 1)
    log = Path(args.log) if args.log else None
    if log is not None and log.exists():
        raise ConfigError(f"--log {log} exists: choose a new folder")
    outcome = run_scenario(campaign, args.index, log=log)
    width = max(map(len, outcome.row))
    for key, value in outcome.row.items():
        print(f"{key:<{width}}  {value}")
    try:
        recorded = next((r for r in read_results(args.dir) if int(r["index"]) == args.index), None)
    except OSError:
        recorded = None
    if recorded is None:
        print(f"scenario {args.index} is not in {args.dir}/results.csv yet", file=sys.stderr)
        return 0
    diff = [k for k in recorded if recorded[k] != outcome.row.get(k, "")]
    if diff:
        print(f"differs from results.csv in: {', '.join(diff)}", file=sys.stderr)
        return 1
    print("same row as in results.csv", file=sys.stderr)
    return 0
