"""Campaign benchmark: what running scenarios as a campaign costs beyond the runs themselves.

Runs the whole command ``swerve campaign run`` on a bench campaign (N robots drawn from the
smoke campaign's distributions, each on the first 6 s of the paper's line, realistic physics,
no calibration) with the process pool at 1 and 2 workers and, with ``--ray``, on a local Ray
(``--ray auto``, inside ``unshare -n -p`` with loopback only). For each: wall time of the
command, the sum of the scenarios' own times on their workers (records.jsonl ``run_s``:
emulator start, gains, the lockstep run), the overhead ``wall - busy / workers`` as a share of
the wall time, scenarios per second, and whether results.csv is byte-identical to the first
engine's. ``--repeat R`` repeats each and reports medians (the machine is shared).

Run: ``.venv/bin/python bench/bench_campaign.py [--scenarios 8] [--repeat 1] [--ray]``; prints
a Markdown table for BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchutil import cpu_model

CAMPAIGN = """\
name: bench
seed: 5
samples: {n}
trajectories: [{traj}]
profiles: [realistic]
parameters:
  tolerances.wheel_radius_scale: {{dist: normal, mean: 1.0, std: 0.01, min: 0.97, max: 1.03, wheels: each}}
  tolerances.steer_zero_offset_rad: {{dist: uniform, min: -0.02, max: 0.02, wheels: each}}
  contact.friction_coefficient: {{dist: choice, values: [0.6, 0.8, 1.0]}}
"""


def run(file: Path, out: Path, extra: list[str], ray: bool) -> dict:
    argv = [sys.executable, "-m", "swerve.tools.cli", "campaign", "run", str(file), "--out", str(out),
            "--no-plots", *extra]
    env = dict(os.environ)
    if ray:
        env.update(RAY_AUTH_MODE="disabled", RAY_USAGE_STATS_ENABLED="0")
        argv = ["unshare", "-n", "-p", "-f", "--mount-proc", "sh", "-c", "ip link set lo up; " + shlex.join(argv)]
    t0 = time.monotonic()
    subprocess.run(argv, check=True, capture_output=True, env=env)
    wall = time.monotonic() - t0
    busy = sum(json.loads(line)["run_s"] for line in (out / "records.jsonl").read_text().splitlines())
    return dict(wall=wall, busy=busy, csv=(out / "results.csv").read_bytes())


def main() -> None:
    from swerve.configs import shipped

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--ray", action="store_true", help="also a local Ray (needs ray, root and unshare)")
    args = ap.parse_args()
    engines = [("pool, 1 worker", ["--workers", "1"], 1, False), ("pool, 2 workers", ["--workers", "2"], 2, False)]
    if args.ray:
        engines.append(("Ray auto, 2 CPUs", ["--ray", "auto", "--workers", "2"], 2, True))
    load0 = os.getloadavg()[0]
    rows, first_csv = [], None
    with tempfile.TemporaryDirectory() as tmp:
        file = Path(tmp) / "bench.yaml"
        file.write_text(CAMPAIGN.format(n=args.scenarios, traj=shipped("campaigns/trajectories/line-6s.yaml")))
        for name, extra, workers, ray in engines:
            res = [run(file, Path(tmp) / f"{name}-{r}".replace(" ", "_").replace(",", ""), extra, ray)
                   for r in range(args.repeat)]
            wall = statistics.median(r["wall"] for r in res)
            busy = statistics.median(r["busy"] for r in res)
            first_csv = first_csv or res[0]["csv"]
            same = all(r["csv"] == first_csv for r in res)
            overhead = max(0.0, wall - busy / workers) / wall
            rows.append((name, wall, busy, overhead, args.scenarios / wall, same))
    base = rows[0][4]
    print(f"\nCampaign of {args.scenarios} scenarios (6 s line, realistic, lockstep), median of {args.repeat}; "
          f"{cpu_model()}, {os.cpu_count()} CPUs, load average {load0:.2f} -> {os.getloadavg()[0]:.2f}, "
          f"{time.strftime('%Y-%m-%d')}.\n")
    print("| engine | wall s | scenario time s | overhead (share of wall) | scenarios/s | vs 1 worker | "
          "results.csv as pool/1 |")
    print("|---|---|---|---|---|---|---|")
    for name, wall, busy, overhead, rate, same in rows:
        print(f"| {name} | {wall:.1f} | {busy:.1f} | {overhead * 100:.1f} % | {rate:.3f} | {rate / base:.2f}x | "
              f"{'identical' if same else 'DIFFERENT'} |")


if __name__ == "__main__":
    main()
