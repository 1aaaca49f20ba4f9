"""Run-log write cost: microseconds and bytes per control cycle.

Usage: python bench/bench_logs.py [--cycles N]. Writes N synthetic cycles (circle with noise,
emulator: all topics incl. /true_pose) for several flush intervals and reports the median
and 99th-percentile cost of ``RunLogWriter.write``, the bag size per cycle, and the read-back
time. The loop budget is tau = 16 ms.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "tools" / "logs"))
import synthetic  # noqa: E402

from swerve.tools.logs import RunLogWriter, read_log  # noqa: E402


def bench(n: int, flush_every: int, tmp: Path) -> dict:
    recs = synthetic.records(n)
    path = tmp / f"bench_f{flush_every}"
    dt = np.empty(n)
    cpu = np.empty(n)
    t_open = time.perf_counter()
    with RunLogWriter(path, synthetic.META, flush_every=flush_every) as w:
        t_open = time.perf_counter() - t_open
        for k, r in enumerate(recs):
            t0, c0 = time.perf_counter(), time.thread_time()
            w.write(r)
            dt[k], cpu[k] = time.perf_counter() - t0, time.thread_time() - c0
    size = sum(p.stat().st_size for p in path.iterdir())
    t0 = time.perf_counter()
    assert len(read_log(path)) == n
    t_read = time.perf_counter() - t0
    return dict(flush=flush_every, med=np.median(dt) * 1e6, p99=np.percentile(dt, 99) * 1e6,
                mx=dt.max() * 1e6, cpu_p99=np.percentile(cpu, 99) * 1e6, cpu_mx=cpu.max() * 1e6, bpc=size / n, open_ms=t_open * 1e3, read_us=t_read / n * 1e6)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=5000)
    args = ap.parse_args()
    print(f"{args.cycles} cycles per case")
    print("| flush_every | write median (µs) | write p99 (µs) | write max (µs) | CPU p99 (µs) | CPU max (µs) | bytes/cycle | open (ms) | read (µs/cycle) |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as d:
        for fe in (1, 8, 64):
            r = bench(args.cycles, fe, Path(d))
            print(f"| {r['flush']} | {r['med']:.0f} | {r['p99']:.0f} | {r['mx']:.0f} | {r['cpu_p99']:.0f} | {r['cpu_mx']:.0f} | {r['bpc']:.0f} "
                  f"| {r['open_ms']:.0f} | {r['read_us']:.0f} |")


if __name__ == "__main__":
    main()
