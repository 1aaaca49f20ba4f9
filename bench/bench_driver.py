"""Driver benchmark: codec throughput and the full 8-servo cycle over a pty.

Usage: python bench/bench_driver.py [--cycles N] [--no-write]. Measures
  1. encode/decode throughput of ``driver.packets`` / ``driver.parser`` (ops/s),
  2. one robot cycle over a pty against ``emulator.Emulator`` (8 servos): one Bulk Write of
     the 8 goals + one Sync Read (or Fast Sync Read) of 126..135, wall and CPU time per cycle,
     with and without cable timing (``wire_timing``: replies paced at 10 bits/byte, 1 Mbps),
  3. the same cycle through dynamixel-sdk 4.1 (GroupBulkWrite + GroupSyncRead) for reference.
Results are printed and written to the "## Driver" section of BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from swerve.driver import packets as pk  # noqa: E402
from swerve.driver.bus import Bus  # noqa: E402
from swerve.driver.parser import PacketParser  # noqa: E402
from swerve.driver.robot_config import load_robot_config  # noqa: E402
from swerve.driver.wheelset import WheelSet  # noqa: E402
from swerve.emulator.server import LinkSettings  # noqa: E402
from swerve.emulator.factory import build_emulator  # noqa: E402
from swerve.emulator.timing import Frozen  # noqa: E402
from benchutil import cpu_model, write_section  # noqa: E402

SECTION = "## Driver"


def rate(fn, min_s: float = 0.5) -> float:
    """Calls per second of ``fn`` over at least ``min_s``."""
    n, t0 = 0, time.perf_counter()
    batch = 200 if min_s > 0 else 1
    while True:
        for _ in range(batch):
            fn()
        n += batch
        dt = time.perf_counter() - t0
        if dt >= min_s:
            return n / dt


def codec() -> list[tuple[str, float]]:
    goals = {i: (100 * i).to_bytes(4, "little", signed=True) for i in range(1, 9)}
    bulk = [(i, 104 if i < 5 else 116, (42 * i).to_bytes(4, "little")) for i in range(1, 9)]
    reply = pk.StatusPacket(3, 0, bytes(range(10))).encode()
    eight = b"".join(pk.StatusPacket(i, 0, bytes(range(10))).encode() for i in range(1, 9))
    fast = pk.FastStatus(tuple(pk.StatusPacket(i, 0, bytes(range(10))) for i in range(1, 9))).encode()
    parser = PacketParser()
    bombs = b"\xff\xff\xfd\x00\x01\xf0\x03" * ((1 << 20) // 7) + reply   # legal LENGTH 1008

    def parse_bombs() -> None:
        p = PacketParser()
        for i in range(0, len(bombs), 4096):
            p.feed(bombs[i:i + 4096])

    return [
        ("encode Sync Write, 8 x 4 bytes", rate(lambda: pk.sync_write(116, 4, goals).encode())),
        ("encode Bulk Write, 8 goals", rate(lambda: pk.bulk_write(bulk).encode())),
        ("encode Sync Read request, 8 IDs", rate(lambda: pk.sync_read(126, 10, range(1, 9)).encode())),
        ("decode one 10-byte status (StatusPacket.decode)", rate(lambda: pk.StatusPacket.decode(reply))),
        ("parse 8 statuses from one chunk (PacketParser.feed)", rate(lambda: parser.feed(eight))),
        ("decode Fast Sync Read reply, 8 x 10 bytes", rate(lambda: pk.FastStatus.decode(fast, [10] * 8))),
        ("resync through 1 MiB of header bombs, 4 KiB chunks (PacketParser.feed)",
         rate(parse_bombs, min_s=0.0)),
    ]


def cycle(cycles: int, *, fast: bool, wire_timing: bool) -> dict:
    cfg = load_robot_config()
    with build_emulator(load_robot_config(ROOT / "configs" / "robot.yaml"), link=LinkSettings(wire_timing=wire_timing),
                        timing=Frozen()) as emu, \
            Bus(emu.port, cfg.link.baud, timeout_margin_s=0.2) as bus, \
            WheelSet(bus, cfg, fast=fast) as ws:
        ws.configure()
        ws.enable()
        for _ in range(20):  # warm up
            ws.write_goals([1.0] * 4, [0.1, 0.2, 0.2, 0.1])
            ws.read_state()
        wall = []
        cpu0, t0 = time.process_time(), time.perf_counter()
        for k in range(cycles):
            a = time.perf_counter()
            ws.write_goals([1.0] * 4, [0.1, -0.2, -0.2, 0.1] if k % 2 else [0.1, 0.2, 0.2, 0.1])
            ws.read_state()
            wall.append(time.perf_counter() - a)
        total = time.perf_counter() - t0
        cpu = time.process_time() - cpu0
    wall.sort()
    return {"median_ms": 1e3 * statistics.median(wall), "p99_ms": 1e3 * wall[int(0.99 * (len(wall) - 1))],
            "hz": cycles / total, "cpu_ms": 1e3 * cpu / cycles}


def sdk_cycle(cycles: int) -> dict | None:
    try:
        import dynamixel_sdk as dxl
    except ImportError:
        return None
    with build_emulator(timing=Frozen()) as emu:
        for i in range(1, 9):  # same Return Delay Time as the WheelSet runs
            emu.servo(i).write("return_delay_time", 0)
        port = dxl.PortHandler(emu.port)
        port.openPort()
        port.setBaudRate(1_000_000)
        ph = dxl.PacketHandler(2.0)
        reader = dxl.GroupSyncRead(port, ph, 126, 10)
        for i in range(1, 9):
            reader.addParam(i)
        wall = []
        cpu0, t0 = time.process_time(), time.perf_counter()
        for _ in range(cycles):
            a = time.perf_counter()
            w = dxl.GroupBulkWrite(port, ph)
            for i in range(1, 9):
                w.addParam(i, 104 if i < 5 else 116, 4, [42, 0, 0, 0])
            w.txPacket()
            if reader.txRxPacket() != dxl.COMM_SUCCESS:
                raise RuntimeError("SDK sync read failed")
            [reader.getData(i, 132, 4) for i in range(1, 9)]
            wall.append(time.perf_counter() - a)
        total = time.perf_counter() - t0
        cpu = time.process_time() - cpu0
        port.closePort()
    wall.sort()
    return {"median_ms": 1e3 * statistics.median(wall), "p99_ms": 1e3 * wall[int(0.99 * (len(wall) - 1))],
            "hz": cycles / total, "cpu_ms": 1e3 * cpu / cycles}


def loadavg() -> str:
    try:
        return " ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "?"


def render(codec_rows, cycle_rows, sdk, cycles) -> str:
    lines = [SECTION, "",
             f"Date {datetime.date.today().isoformat()}, `nproc` = {os.cpu_count()}, CPU \"{cpu_model()}\", "
             f"load average {loadavg()} at the end, Python {platform.python_version()}. "
             f"Command: `.venv/bin/python bench/bench_driver.py --cycles {cycles}`.", "",
             "Codec (pure Python, one core):", "",
             "| operation | ops/s | µs/op |", "|---|---|---|"]
    for name, r in codec_rows:
        lines.append(f"| {name} | {r:,.0f} | {1e6 / r:.1f} |")
    lines += ["", "Full 8-servo cycle over a pty against `emulator.Emulator` (one Bulk Write of "
              "`[v1, v1, v1, v1, δ1, δ2, δ2, δ1]` + one Sync Read of Present Current/Velocity/Position "
              "126..135, converted to SI). Emulator Return Delay Time 0 (from robot.yaml); the emulator's "
              "threads share the 2 cores with the client. CPU = client+emulator process time per cycle.", "",
              "| variant | median ms | p99 ms | cycles/s | CPU ms/cycle |", "|---|---|---|---|---|"]
    for name, r in cycle_rows:
        lines.append(f"| {name} | {r['median_ms']:.2f} | {r['p99_ms']:.2f} | {r['hz']:.0f} | {r['cpu_ms']:.2f} |")
    if sdk:
        lines.append(f"| dynamixel-sdk 4.1 GroupBulkWrite + GroupSyncRead (busy-wait receive), no cable timing | {sdk['median_ms']:.2f} | {sdk['p99_ms']:.2f} | {sdk['hz']:.0f} | "
                     f"{sdk['cpu_ms']:.2f} |")
    lines += ["", "On a U2D2 at 1 Mbps with the latency timer at 1 ms, expect the cycle to be bounded by "
              "the adapter (≈ 2 × 1 ms latency + ~0.3 ms on the wire), not by this code.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=1000)
    ap.add_argument("--no-write", action="store_true", help="print only; leave BENCHMARKS.md alone")
    args = ap.parse_args()
    codec_rows = codec()
    cycle_rows = [
        ("Sync Read, no cable timing", cycle(args.cycles, fast=False, wire_timing=False)),
        ("Fast Sync Read, no cable timing", cycle(args.cycles, fast=True, wire_timing=False)),
        ("Sync Read, cable timing 1 Mbps", cycle(args.cycles, fast=False, wire_timing=True)),
        ("Fast Sync Read, cable timing 1 Mbps", cycle(args.cycles, fast=True, wire_timing=True)),
    ]
    sdk = sdk_cycle(min(args.cycles, 300))
    text = render(codec_rows, cycle_rows, sdk, args.cycles)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)


if __name__ == "__main__":
    main()
