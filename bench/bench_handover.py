"""What one hand-over between two processes costs on this machine, over a pty.

Every lockstep cycle and every bus round trip is a message from one process to another and
back, through a pseudo-terminal. This times the bare round trip with no work on either side:
the client writes one byte to the pty's slave end, the server (another process, blocked in
``select`` on the master) reads it and writes one byte back. The client waits for the answer
either blocked in ``select`` (as ``driver.transport`` does), or polling a non-blocking read in a
loop (as dynamixel-sdk's ``PortHandler`` does), with the two processes free to use any core or
both pinned to one. It reports the round-trip time and the client's CPU per round trip.
``--pm-qos`` repeats the two any-core ways while holding a PM QoS CPU latency request of 0 us
(idle CPUs poll instead of halting; needs root): the difference is what a halted CPU's wake-up
costs a blocked client.

    .venv/bin/python bench/bench_handover.py [--count 5000] [--repeat 3] [--pm-qos] [--write]

``--write`` replaces the section "## Hand-over cost" of BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import pty
import select
import statistics
import time
import tty

from benchutil import CPU_DMA_LATENCY, CpuLatencyRequest, check_cpu_latency_request, cpu_model, write_section

SECTION = "## Hand-over cost"
WAYS = (("blocking select, any core", False, False),
        ("busy-polling read, any core", True, False),
        ("blocking select, one core", False, True))
#: The ways measured again with idle CPUs polling (``--pm-qos``).
QOS_WAYS = WAYS[:2]


def _serve(master: int, count: int) -> None:
    for _ in range(count):
        select.select([master], [], [])
        os.write(master, os.read(master, 64))
    # closing the master hangs the pty up and drops a reply still on its way: stay until the
    # client has closed its end (the read then fails with EIO)
    try:
        while os.read(master, 64):
            pass
    except OSError:
        pass


def round_trip(count: int, poll: bool, one_core: bool) -> tuple[float, float]:
    """Median round-trip time and mean client CPU per round trip, us."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    pid = os.fork()
    if pid == 0:                      # the server
        try:
            os.close(slave)
            if one_core:
                os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
            _serve(master, count)
        finally:
            os._exit(0)
    os.close(master)
    if one_core:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    os.set_blocking(slave, not poll)
    times = []
    cpu0 = time.process_time()
    try:
        for _ in range(count):
            t0 = time.perf_counter()
            os.write(slave, b"x")
            if poll:
                while True:
                    try:
                        if os.read(slave, 64):
                            break
                    except BlockingIOError:
                        pass
            else:
                select.select([slave], [], [])
                os.read(slave, 64)
            times.append(time.perf_counter() - t0)
    finally:
        cpu = time.process_time() - cpu0
        os.close(slave)
        os.waitpid(pid, 0)
        if one_core:
            os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
    return 1e6 * statistics.median(times), 1e6 * cpu / count


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--count", type=int, default=5000, help="round trips per run")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--pm-qos", action="store_true",
                    help="also measure the any-core ways with idle CPUs polling (PM QoS 0 us; root)")
    ap.add_argument("--write", action="store_true", help="write the section of BENCHMARKS.md")
    args = ap.parse_args()
    if args.count < 1 or args.repeat < 1:
        ap.error("--count and --repeat must be >= 1")
    if args.pm_qos:
        check_cpu_latency_request(ap)
    lines = [SECTION, "",
             f"{dt.date.today()}; `nproc` = {os.cpu_count()}; CPU {cpu_model()}; Python "
             f"{platform.python_version()}; load {os.getloadavg()[0]:.2f} at start; "
             f"`bench/bench_handover.py --count {args.count} --repeat {args.repeat}"
             f"{' --pm-qos' if args.pm_qos else ''}`.", "",
             "One byte to another process over a pty and one byte back, no work on either side "
             "(medians of each run; CPU: the client's, per round trip). Idle CPUs: `halt` is the "
             "machine's own idle policy; `poll` holds a PM QoS CPU latency request of 0 us "
             f"(`{CPU_DMA_LATENCY}`), so an idle CPU spins in the kernel instead of halting.", "",
             "| client waits by | idle CPUs | run | round trip us | client CPU us |",
             "|---|---|---:|---:|---:|"]
    cases = [(way, "halt") for way in WAYS] + ([(way, "poll") for way in QOS_WAYS] if args.pm_qos else [])
    for (name, poll, one_core), idle in cases:
        for k in range(args.repeat):
            if idle == "poll":
                with CpuLatencyRequest(0):
                    rt, cpu = round_trip(args.count, poll, one_core)
            else:
                rt, cpu = round_trip(args.count, poll, one_core)
            lines.append(f"| {name} | {idle} | {k + 1} | {rt:.1f} | {cpu:.1f} |")
            print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if args.write:
        write_section(SECTION, text)
    else:
        print(text)


if __name__ == "__main__":
    main()
