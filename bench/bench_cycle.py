"""One lockstep control cycle seen from the controller: where its wall time goes.

Runs the line (40 s of robot time, log on) in lockstep against the emulator process, as
``swerve run --trajectory line --emulate --lockstep --log DIR`` does, and stamps (monotonic
clock, ns) the start and end of every call the cycle makes across the process boundary or to
the law: the pty writes and reads (:class:`swerve.driver.transport.Transport`), the control
socket's requests and answers (:class:`swerve.tools.run.lockstep.LockstepLoopClock`), the law
(:meth:`swerve.controller.tracking.TrackingLaw.step`) and the log write
(:meth:`swerve.tools.logs.bag.RunLogWriter.write`). It prints the cycle's most common sequence
of those events with the median wall time between each two, so the waits (the emulator's work
plus a hand-over) stand beside the controller's own work, and the count per cycle of pty
writes, pty reads and control requests.

Run: ``.venv/bin/python bench/bench_cycle.py [--emulator-config realistic] [--skip 200]``.
The stamps wrap methods of this process only (the emulator is untouched); each costs about a
microsecond. Wall times on a shared machine move with the neighbours: compare runs made in the
same minutes.
"""
from __future__ import annotations

import argparse
import collections
import os
import statistics
import tempfile
import time
from pathlib import Path

from benchutil import cpu_model

#: (class path, method, label at entry, label at exit or None)
STAMPED = (
    ("swerve.driver.transport:Transport", "write", "pty write", "pty written"),
    ("swerve.driver.transport:Transport", "read_packets", "pty wait", "pty reply in"),
    ("swerve.tools.run.lockstep:LockstepLoopClock", "_send", "request", "request sent"),
    ("swerve.tools.run.lockstep:LockstepLoopClock", "_answer", "answer wait", "answer in"),
    ("swerve.controller.tracking:TrackingLaw", "step", "law", "law done"),
    ("swerve.tools.logs.bag:RunLogWriter", "write", "log", "log written"),
)


def _stamp(marks: list, spec) -> None:
    """Wrap one method so that each call appends ``(label, ns)`` at entry (and exit)."""
    import importlib

    path, name, enter, leave = spec
    module, cls_name = path.split(":")
    cls = getattr(importlib.import_module(module), cls_name)
    method = getattr(cls, name)
    clock = time.monotonic_ns

    def stamped(*args, **kwargs):
        marks.append((enter, clock()))
        try:
            return method(*args, **kwargs)
        finally:
            if leave is not None:
                marks.append((leave, clock()))

    setattr(cls, name, stamped)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--emulator-config", default="ideal", help="physics profile (default ideal)")
    ap.add_argument("--trajectory", default="line")
    ap.add_argument("--skip", type=int, default=200, help="cycles left out at the start (default 200)")
    args = ap.parse_args()
    marks: list[tuple[str, int]] = []
    for spec in STAMPED:
        _stamp(marks, spec)
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        res = run_tracking(RunRequest(trajectory=args.trajectory, emulate=True, lockstep=True, time_scale=None,
                                      log=Path(tmp) / "log", emulator_config=args.emulator_config))
    s = res.summary.to_dict()
    # a cycle runs from the end of one log write to the end of the next
    ends = [i for i, (label, _) in enumerate(marks) if label == "log written"]
    shapes = collections.defaultdict(list)
    for a, b in zip(ends, ends[1:]):
        shapes[tuple(label for label, _ in marks[a:b + 1])].append(a)
    shape, starts = max(shapes.items(), key=lambda kv: len(kv[1]))
    starts = starts[args.skip:] or starts
    print(f"date {time.strftime('%Y-%m-%d %H:%M')}, nproc {os.cpu_count()}, CPU {cpu_model()}, "
          f"load {load0:.1f} before / {os.getloadavg()[0]:.1f} after, physics {args.emulator_config}, "
          f"{s['cycles']} cycles, controller CPU per cycle p50 {s['host_cpu_p50_ms']:.3f} ms")
    print(f"{len(starts)} cycles of the most common sequence ({len(ends) - 1} in all); median wall time "
          "from each event to the next, µs:\n")
    print("| from | to | µs |")
    print("|---|---|---|")
    total = []
    for j in range(len(shape) - 1):
        gaps = [marks[a + j + 1][1] - marks[a + j][1] for a in starts]
        print(f"| {shape[j]} | {shape[j + 1]} | {statistics.median(gaps) / 1e3:.1f} |")
    for a in starts:
        total.append(marks[a + len(shape) - 1][1] - marks[a][1])
    print(f"| **cycle** | | **{statistics.median(total) / 1e3:.1f}** |")
    counts = collections.Counter(shape)
    print(f"\nper cycle: {counts['pty write']} pty writes, {counts['pty wait']} pty reads awaited, "
          f"{counts['request']} control requests, {counts['answer wait']} answers awaited")


if __name__ == "__main__":
    main()
