"""The controller's side of a lockstep run alone: a recorded run replayed without the emulator.

A lockstep run is deterministic: the controller writes the same bytes to the pty and sends the
same control requests every time, and the emulator answers them with the same bytes. This
records a ``swerve run --trajectory line --emulate --lockstep --log DIR`` (the emulator's
replies on the pty and its answers on the control socket, per request), then runs the same
controller code again against a pty and a socket that hand back the recorded answers the moment
each request is made. The controller then never waits: its thread CPU time per step is its work
alone, without the neighbours' or the emulator's, and every request is checked against the
recording (a replay that sends other bytes stops with an error). The replayed log's export is
compared with the recorded one's.

It prints the median thread CPU per step of the cycle (the steps of ``bench/bench_cycle.py``),
the controller's **critical chain** (from the Sync Read's reply, read and decoded, to the
``advance`` request sent: the part of the cycle the emulator waits for) and the loop's CPU per cycle.

Run: ``.venv/bin/python bench/bench_replay.py [--record FILE] [--replays 3]``. ``--record``
keeps the recording (``.pkl``) and reuses it if present, so another checkout's interpreter can
replay the same run: ``OLD/.venv/bin/python bench/bench_replay.py --record /tmp/line.pkl``.
For an instruction count of the critical chain alone (independent of the neighbours), build
``bench/cg_toggle.c`` (its header says how) and run one replay under callgrind::

    valgrind --tool=callgrind --collect-atstart=no --callgrind-out-file=cg.out \
        .venv/bin/python bench/bench_replay.py --record R.pkl --replays 1 --no-stamps --callgrind /tmp/cg_toggle.so

``callgrind_annotate cg.out | head`` then gives the chain's instructions over all the run's cycles.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import socket
import statistics
import tempfile
import time
import tty
from pathlib import Path

from bench_cycle import STAMPED
from benchutil import cpu_model

#: Bus timeout slack in a replay, s.
REPLAY_TIMEOUT_MARGIN_S = 60.0
#: Recordings made at most to get one without a late reply.
RECORD_TRIES = 5

def _cls(path: str):
    import importlib

    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


def _wrap(path: str, name: str, make):
    """Replace ``path``'s method ``name`` with ``make(original)``; returns an undo."""
    cls = _cls(path)
    original = getattr(cls, name)
    setattr(cls, name, make(original))
    return lambda: setattr(cls, name, original)


def _export(log: Path) -> str:
    """sha256 of the log's CSV export (what the project's export hashes are)."""
    from swerve.tools.logs import read_log
    from swerve.tools.logs.csv_export import export_csv

    out = log.parent / "export.csv"
    export_csv(read_log(log), out)
    return hashlib.sha256(out.read_bytes()).hexdigest()


def record(physics: str, trajectory: str) -> dict:
    """Run with the emulator; returns the pty writes with the bytes read after each, and the
    control requests with their answers, in order."""
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    writes: list[list] = []          # [bytes written, bytes read until the next write]
    requests: list[list] = []        # [request line, answer line]

    def write(original):
        def w(self, data):
            writes.append([bytes(data), b""])
            return original(self, data)
        return w

    def read_chunk(original):
        def r(self, remaining_s):
            data = original(self, remaining_s)
            if data and writes:
                writes[-1][1] += data
            return data
        return r

    def send(original):
        def s(self, request):
            original(self, request)
            requests.append([request, None])
        return s

    def answer(original):
        def a(self):
            words = original(self)
            for req in reversed(requests):
                if req[1] is None:
                    req[1] = " ".join(words)
                    break
            return words
        return a

    undo = [_wrap("swerve.driver.transport:Transport", "write", write),
            _wrap("swerve.driver.transport:Transport", "_read_chunk", read_chunk),
            _wrap("swerve.tools.run.lockstep:LockstepLoopClock", "_send", send),
            _wrap("swerve.tools.run.lockstep:LockstepLoopClock", "_answer", answer)]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            log = Path(tmp) / "log"
            run_tracking(RunRequest(trajectory=trajectory, emulate=True, lockstep=True, time_scale=None,
                                    log=log, emulator_config=physics))
            digest = _export(log)
    finally:
        for u in undo:
            u()
    return dict(writes=writes, requests=requests, export=digest, physics=physics, trajectory=trajectory)


class _Peer:
    """The emulator's ends of a pty and a control socket, answering from a recording."""

    def __init__(self, rec: dict, tmp: Path):
        self.writes, self.requests = rec["writes"], rec["requests"]
        self.nw = self.nr = 0
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.path = str(tmp / "control")
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.server.bind(self.path)
        self.server.listen(1)
        self.conn = None
        self.buf = b""
        #: Thread CPU spent here, ns: taken off the controller's stamps.
        self.spent_ns = 0

    def wrote(self, data: bytes) -> None:
        """The controller wrote ``data`` to the pty: check it, send the recorded reply."""
        t0 = time.thread_time_ns()
        want, reply = self.writes[self.nw]
        got = b""
        while len(got) < len(data):
            got += os.read(self.master, 4096)
        if got != want:
            raise RuntimeError(f"pty write {self.nw} differs from the recording: {got.hex()} != {want.hex()}")
        self.nw += 1
        if reply:
            os.write(self.master, reply)
        self.spent_ns += time.thread_time_ns() - t0

    def sent(self, request: str) -> None:
        """The controller sent ``request``: check it, send the recorded answer."""
        t0 = time.thread_time_ns()
        if self.conn is None:
            self.conn, _ = self.server.accept()
        while b"\n" not in self.buf:
            self.buf += self.conn.recv(4096)
        line, self.buf = self.buf.split(b"\n", 1)
        want, answer = self.requests[self.nr]
        if line.decode() != want:
            raise RuntimeError(f"request {self.nr} differs from the recording: {line!r} != {want!r}")
        self.nr += 1
        if answer is not None:
            self.conn.sendall(answer.encode() + b"\n")
        self.spent_ns += time.thread_time_ns() - t0

    def close(self) -> None:
        for fd in (self.master, self.slave):
            os.close(fd)
        if self.conn is not None:
            self.conn.close()
        self.server.close()


class _Chain:
    """Switches callgrind's collection on while the controller is on the critical chain: in the
    tracking loop, from a reply's wait to the ``advance`` request sent, the recording's answers
    left out."""

    def __init__(self, toggle):
        self.toggle, self.on = toggle, False
        self.armed = False          # inside the tracking loop

    def start(self) -> None:
        if self.armed and not self.on:
            self.toggle()
            self.on = True

    def stop(self) -> None:
        if self.on:
            self.toggle()
            self.on = False


def _aside(meter: _Chain | None, work, arg, resume: bool = True) -> None:
    """``work(arg)`` (the recording's side) outside the chain's count; the count goes on after it
    if it was on and ``resume``."""
    on = meter is not None and meter.on
    if on:
        meter.stop()
    work(arg)
    if on and resume:
        meter.start()


def replay(rec: dict, stamps: bool, extra: tuple = (), toggle=None) -> dict:
    """Run the controller against the recording; returns the step CPU times and the export.
    ``toggle``: callgrind's collection switch, flipped at the ends of the critical chain."""
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    marks: list[tuple[str, int]] = []
    meter = _Chain(toggle) if toggle is not None else None
    with tempfile.TemporaryDirectory() as tmp:
        peer = _Peer(rec, Path(tmp))

        def clock():
            return time.thread_time_ns() - peer.spent_ns

        def write(original):
            def w(self, data):
                original(self, data)
                _aside(meter, peer.wrote, bytes(data))
            return w

        def send(original):
            def s(self, request):
                original(self, request)
                _aside(meter, peer.sent, request, resume=not request.startswith("advance "))
            return s

        def read(original):
            def r(self, deadline):
                meter.start()
                return original(self, deadline)
            return r

        undo = [_wrap("swerve.driver.transport:Transport", "write", write),
                _wrap("swerve.tools.run.lockstep:LockstepLoopClock", "_send", send)]
        def loop(original):
            def run(self, start_state):
                meter.armed = True
                try:
                    return original(self, start_state)
                finally:
                    meter.armed = False
                    meter.stop()
            return run

        def law(original):
            def step(self, t_s, state):
                out = original(self, t_s, state)
                if out.finished:        # the loop ends here: its teardown is not a cycle's chain
                    meter.armed = False
                    meter.stop()
                return out
            return step

        if meter is not None:
            undo.append(_wrap("swerve.driver.transport:Transport", "read_packets", read))
            undo.append(_wrap("swerve.tools.run.loop:TrackingLoop", "run", loop))
            undo.append(_wrap("swerve.controller.tracking:TrackingLaw", "step", law))
        if stamps:
            for path, name, enter, leave in STAMPED + extra:
                def make(original, enter=enter, leave=leave):
                    def stamped(*args, **kwargs):
                        marks.append((enter, clock()))
                        try:
                            return original(*args, **kwargs)
                        finally:
                            marks.append((leave, clock()))
                    return stamped
                undo.append(_wrap(path, name, make))
        try:
            log = Path(tmp) / "log"
            # the recorded replies are there when asked for: no timeout may fire, even under callgrind
            res = run_tracking(RunRequest(trajectory=rec["trajectory"], lockstep=True, control=peer.path,
                                          port=peer.port, time_scale=None, log=log,
                                          timeout_margin_s=REPLAY_TIMEOUT_MARGIN_S))
            digest = _export(log)
        finally:
            if meter is not None:
                meter.stop()
            for u in reversed(undo):
                u()
            peer.close()
    if peer.nw != len(rec["writes"]) or peer.nr != len(rec["requests"]):
        raise RuntimeError(f"replay made {peer.nw} writes and {peer.nr} requests, the recording "
                           f"{len(rec['writes'])} and {len(rec['requests'])}")
    s = res.summary.to_dict()
    return dict(marks=marks, export=digest, cycles=s["cycles"], loop_cpu_ms=s["loop_cpu_s"] / s["cycles"] * 1e3,
                host_cpu_p50_ms=s["host_cpu_p50_ms"])


def steps(marks, skip: int):
    """The most common cycle's sequence and, per step, the CPU times (ns) of all its cycles."""
    import collections

    ends = [i for i, (label, _) in enumerate(marks) if label == "log written"]
    shapes = collections.defaultdict(list)
    for a, b in zip(ends, ends[1:]):
        shapes[tuple(label for label, _ in marks[a:b + 1])].append(a)
    shape, starts = max(shapes.items(), key=lambda kv: len(kv[1]))
    starts = starts[skip:] or starts
    gaps = [[marks[a + j + 1][1] - marks[a + j][1] for a in starts] for j in range(len(shape) - 1)]
    return shape, gaps, starts


def chain(shape) -> tuple[int, int]:
    """Indices of the critical chain's ends in ``shape``: the wait for the Sync Read's reply (in a
    replay the reply is there: the wait is the read and the decoding), the advance sent (the
    first "request sent" after the second "pty written")."""
    first = shape.index("pty wait")
    written = [i for i, label in enumerate(shape) if label == "pty written" and i > first]
    last = shape.index("request sent", written[0])
    return first, last


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--emulator-config", default="ideal")
    ap.add_argument("--trajectory", default="line")
    ap.add_argument("--record", type=Path, help="recording file (.pkl): reused if present, else written")
    ap.add_argument("--replays", type=int, default=3)
    ap.add_argument("--skip", type=int, default=200, help="cycles left out at the start (default 200)")
    ap.add_argument("--no-stamps", action="store_true", help="no per-step stamps (for callgrind)")
    ap.add_argument("--callgrind", metavar="LIB", help="shared library built from bench/cg_toggle.c: "
                    "under valgrind --tool=callgrind --collect-atstart=no, collect the critical chain only")
    ap.add_argument("--stamp", action="append", default=[], metavar="MODULE:CLASS.METHOD",
                    help="stamp this method's entry and exit too, e.g. swerve.driver.bus:Bus._exchange")
    args = ap.parse_args()
    if args.record is not None and args.record.exists():
        rec = pickle.loads(args.record.read_bytes())
    else:
        for _ in range(RECORD_TRIES):
            rec = record(args.emulator_config, args.trajectory)
            # a reply late on the wall clock makes the bus ask the emulator what it sent: a
            # request of that run only (the replay's replies are never late); record again
            if not any(req.startswith("sent ") for req, _ in rec["requests"][2:]):
                break
        else:
            raise SystemExit(f"every one of {RECORD_TRIES} recordings had a late reply; try on a quieter machine")
        if args.record is not None:
            args.record.write_bytes(pickle.dumps(rec))
    print(f"date {time.strftime('%Y-%m-%d %H:%M')}, nproc {os.cpu_count()}, CPU {cpu_model()}, "
          f"load {os.getloadavg()[0]:.1f}, physics {rec['physics']}, {rec['trajectory']}, "
          f"{len(rec['writes'])} pty writes and {len(rec['requests'])} requests recorded")
    per_step: list[list[float]] = []
    chains, loops, shape = [], [], None
    toggle = None
    if args.callgrind:
        import ctypes

        toggle = ctypes.CDLL(args.callgrind).cg_toggle
    for n in range(args.replays):
        got = replay(rec, not args.no_stamps, toggle=toggle, extra=tuple(
            (spec.rsplit(".", 1)[0], spec.rsplit(".", 1)[1], spec.rsplit(":", 1)[1], spec.rsplit(":", 1)[1] + " done")
            for spec in args.stamp))
        if got["export"] != rec["export"]:
            raise SystemExit(f"replay {n}: export {got['export'][:8]} differs from the recording's "
                             f"{rec['export'][:8]}")
        loops.append(got["loop_cpu_ms"])
        if args.no_stamps:
            continue
        shape, gaps, starts = steps(got["marks"], args.skip)
        per_step.append([statistics.median(g) / 1e3 for g in gaps])
        a, b = chain(shape)
        marks = got["marks"]
        chains.append(statistics.median(marks[s + b][1] - marks[s + a][1] for s in starts) / 1e3)
    print(f"export {rec['export'][:8]} reproduced by {args.replays} replays; loop CPU per cycle "
          f"(loop_cpu_s / cycles) {' '.join(f'{x:.3f}' for x in loops)} ms")
    if shape is None:
        return
    print("\nmedian thread CPU per step, µs (one column per replay):\n")
    print("| from | to | " + " | ".join(f"#{i + 1}" for i in range(len(per_step))) + " |")
    print("|---|---|" + "---|" * len(per_step))
    for j in range(len(shape) - 1):
        print(f"| {shape[j]} | {shape[j + 1]} | " + " | ".join(f"{r[j]:.1f}" for r in per_step) + " |")
    print("| **critical chain** (pty wait .. advance sent) | | "
          + " | ".join(f"**{c:.1f}**" for c in chains) + " |")
    print(f"\ncritical chain median of the replays: {statistics.median(chains):.1f} µs")


if __name__ == "__main__":
    main()
