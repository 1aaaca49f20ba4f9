"""Cost of the pty master's packet mode on the emulator's read path.

The emulator's :class:`~swerve.emulator.pty_link.PtyLink` runs the master in packet mode
(``TIOCPKT``) to see a client's output flush; every read then carries one control byte that
:meth:`PtyLink.read` strips, and a client's input flush (``tcflush(TCIFLUSH)``, which the
project's driver does before every request) makes the master readable once more, for a status
byte alone. This times, in one run and alternating round by round, a client writing one
10-byte Ping to the slave (after ``tcflush(TCIFLUSH)`` as the driver does, and without) and the
master side waiting in ``select`` and reading until it has the Ping: through ``PtyLink.read``
(packet mode) and through a plain ``os.read`` on a pty without packet mode (the peer). It
prints the median time per write+read and the ratios.

    .venv/bin/python bench/bench_pty_read.py [--n 20000] [--rounds 5]
"""
from __future__ import annotations

import argparse
import os
import platform
import select
import statistics
import sys
import time
import termios
import tty
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from swerve.driver.packets import Instruction, InstructionPacket  # noqa: E402
from swerve.emulator.pty_link import PtyLink  # noqa: E402

PING = InstructionPacket(1, Instruction.PING).encode()


def _time(n: int, write_fd: int, wait_fd: int, read, flush_input: bool) -> float:
    """Seconds per write of a Ping and the reads that take it, mean of ``n`` in one go."""
    t0 = time.perf_counter()
    for _ in range(n):
        if flush_input:
            termios.tcflush(write_fd, termios.TCIFLUSH)
        os.write(write_fd, PING)
        got = b""
        while not got:
            select.select([wait_fd], [], [], 1.0)
            got = read()
        if got != PING:
            raise RuntimeError("a read did not return the whole Ping")
    return (time.perf_counter() - t0) / n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20_000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    link = PtyLink()
    client = os.open(link.path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(client)
    master, slave = os.openpty()
    tty.setraw(slave)
    times: dict[tuple[str, bool], list[float]] = {}
    try:
        for _ in range(args.rounds):
            for flush in (False, True):
                times.setdefault(("packet", flush), []).append(
                    _time(args.n, client, link.master, link.read, flush))
                times.setdefault(("plain", flush), []).append(
                    _time(args.n, slave, master, lambda: os.read(master, 4096), flush))
    finally:
        os.close(client)
        link.close()
        os.close(master)
        os.close(slave)
    print(f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
          f"{args.rounds} rounds x {args.n} Pings, load {os.getloadavg()[0]:.1f}")
    for flush in (False, True):
        p, q = statistics.median(times["packet", flush]), statistics.median(times["plain", flush])
        what = "client tcflush(TCIFLUSH) first" if flush else "no client flush"
        print(f"{what:31}: packet mode {p * 1e6:6.2f} us, plain pty {q * 1e6:6.2f} us per write+read, "
              f"ratio {p / q:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
