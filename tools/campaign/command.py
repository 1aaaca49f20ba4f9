"""``swerve campaign``'s work: run (or resume) a campaign, or replay one of its scenarios.

The options are :mod:`swerve.tools.commands.campaign`; :func:`run` takes the parsed command line.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from swerve.core.errors import ConfigError
from swerve.tools.campaign.engines import make_engine, require_ray
from swerve.tools.campaign.report import table, write_summary
from swerve.tools.campaign.runner import run_missing
from swerve.tools.campaign.scenario import run_scenario
from swerve.tools.campaign.spec import load_campaign
from swerve.tools.campaign.store import Store, load_folder, read_results


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
