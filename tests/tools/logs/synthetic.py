"""A synthetic run for the log tests: a 0.5 m circle at 62.5 Hz with measurement noise.

Also runnable as ``python synthetic.py BAG N_CYCLES FLUSH_EVERY``: writes N cycles, prints
``wrote <k>`` after each one and then sleeps inside the ``with`` block, so a test can SIGKILL it mid-run.
"""
from __future__ import annotations

import signal
import sys
import time

import numpy as np

from swerve.tools.logs import CycleFlag, CycleRecord, RunLogWriter

TAU_S = 0.016
META = {"trajectory": "circle", "gains_file": "gains/circle.npz", "time_scale": 1.0,
        "port": "emulator", "period_s": TAU_S, "wheel_radius_m": 0.033,
        "config": {"a_m": 0.1125, "b_m": 0.1125}}


def records(n: int, seed: int = 0, true_pose: bool = True) -> list[CycleRecord]:
    """``n`` cycles of a circle of radius 0.5 m at 0.1 m/s, noisy measurements."""
    return list(iter_records(n, seed, true_pose))


def iter_records(n: int, seed: int = 0, true_pose: bool = True):
    """The cycles of :func:`records`, generated one at a time."""
    rng = np.random.default_rng(seed)
    R, v = 0.5, 0.1
    for k in range(n):
        t = k * TAU_S
        th = v / R * t
        ref = np.array([R * np.sin(th), R * (1 - np.cos(th)), th])
        est = ref + rng.normal(0, [2e-3, 2e-3, 5e-3])
        d1 = np.arctan(0.1125 / R)
        cmd_steer = np.array([d1, -d1, -d1, d1]) + rng.normal(0, 1e-3, 4)
        yield CycleRecord(
            t_s=t, stamp_ns=1_790_000_000_000_000_000 + k * 16_000_000 + int(rng.integers(0, 50_000)),
            cycle=k, period_s=TAU_S * (1 + rng.normal(0, 0.01)),
            cmd_drive_radps=np.full(4, v / 0.033), cmd_steer_rad=cmd_steer, cmd_v1_mps=v,
            cmd_omega_radps=rng.normal(0, 0.02, 2),
            meas_drive_radps=v / 0.033 + rng.normal(0, 0.05, 4),
            meas_steer_rad=cmd_steer + rng.normal(0, 0.01, 4),
            meas_current_a=rng.uniform(0.05, 0.3, 8),
            est_pose=est, ref_pose=ref, ref_delta=[d1, -d1],
            true_pose=ref + rng.normal(0, 1e-3, 3) if true_pose else np.full(3, np.nan),
            flags=int(CycleFlag.OVERRUN) if k % 97 == 5 else (int(CycleFlag.STALE) if k % 50 == 7 else 0))


def write(path, recs, flush_every: int = 1) -> None:
    with RunLogWriter(path, META, flush_every=flush_every) as w:
        for r in recs:
            w.write(r)


if __name__ == "__main__":
    bag, n, flush = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    # Ctrl-C as in a terminal, whatever the starting process left ignored: a pytest-xdist worker
    # was seen with SIGINT ignored (SigIgn in /proc), which Python keeps for its children
    signal.signal(signal.SIGINT, signal.default_int_handler)
    with RunLogWriter(bag, META, flush_every=flush) as w:
        for r in iter_records(n):
            w.write(r)
            print(f"wrote {w.cycles_written}", flush=True)
        time.sleep(60)  # the test kills us here: SIGKILL skips close(), SIGINT (Ctrl-C) does not
