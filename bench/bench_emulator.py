"""Round trips per second of an 8-servo Sync Read over the emulator's pty.

Runs ``swerve emulate`` in a separate process (as a user would), sets every servo's Return
Delay Time to 0 (what ``configs/robot.yaml`` asks for), then for a few seconds each times
Sync Read of Present Position (4 bytes) from IDs 1-8 with dynamixel-sdk 4.1 (unmodified) and
with the project's ``driver.bus.Bus``, without and with ``--wire-timing`` at 1 Mbps. The
wire-time limit is computed from the byte counts (10 bits per byte, no gaps).

    .venv/bin/python bench/bench_emulator.py [--seconds 3] [--no-write]

Writes the section "## Emulator bus" of BENCHMARKS.md (other sections untouched).
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchutil import cpu_model, write_section  # noqa: E402
from swerve.tools.commands.emulate import parse_port_line  # noqa: E402

IDS = list(range(1, 9))
BAUD = 1_000_000
ADDRESS, LENGTH = 132, 4                       # Present Position
SECTION = "## Emulator bus"
DRIVER_MARGIN_S = 0.02


def wire_limit_rtps(nservos: int = 8, length: int = LENGTH, baud: int = BAUD,
                    return_delay_s: float = 0.0) -> tuple[int, float]:
    """Bytes on the wire per Sync Read round trip and the round trips/s the cable allows."""
    instruction = 14 + nservos                 # header..LEN (7) + INST + addr + len (5) + IDs + CRC (2)
    replies = nservos * (11 + length)          # header..LEN (7) + 0x55 + ERR + data + CRC (2)
    nbytes = instruction + replies
    seconds = nbytes * 10 / baud + nservos * return_delay_s
    return nbytes, 1.0 / seconds


class EmulatorProcess:
    def __init__(self, *extra: str):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "swerve.tools.cli", "emulate", "--ids", "1-8", "--baud", str(BAUD), "--frozen",
             *extra],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            self.port, _baud, _ids = parse_port_line(self.proc.stdout.readline())
        except ValueError:
            self.close()
            raise RuntimeError("swerve emulate did not print its port") from None

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _zero_return_delay(port: str) -> None:
    import dynamixel_sdk as sdk

    ph, pk = sdk.PortHandler(port), sdk.PacketHandler(2.0)
    ph.openPort()
    ph.setBaudRate(BAUD)
    try:
        for i in IDS:
            result, err = pk.write1ByteTxRx(ph, i, 9, 0)
            if result != sdk.COMM_SUCCESS or err:
                raise RuntimeError(f"could not set Return Delay Time of ID {i}: {result} {err}")
    finally:
        ph.closePort()


def _rate(fn, seconds: float) -> tuple[float, int]:
    """Calls per second of ``fn`` (returns False on failure) and the failure count."""
    for _ in range(20):
        fn()                                   # warm up
    n = fails = 0
    t0 = time.perf_counter()
    deadline = t0 + seconds
    while time.perf_counter() < deadline:
        if not fn():
            fails += 1
        n += 1
    return n / (time.perf_counter() - t0), fails


def bench_sdk(port: str, seconds: float) -> tuple[float, int]:
    import dynamixel_sdk as sdk

    ph, pk = sdk.PortHandler(port), sdk.PacketHandler(2.0)
    ph.openPort()
    ph.setBaudRate(BAUD)
    group = sdk.GroupSyncRead(ph, pk, ADDRESS, LENGTH)
    for i in IDS:
        group.addParam(i)
    try:
        return _rate(lambda: group.txRxPacket() == sdk.COMM_SUCCESS, seconds)
    finally:
        ph.closePort()


def bench_driver(port: str, seconds: float) -> tuple[float, int] | None:
    try:
        from swerve.driver.bus import Bus
        from swerve.driver.control_table import Reg
        from swerve.driver.errors import DxlError
    except ImportError:
        return None

    # the Bus default margin (2 ms) is meant for hardware; the emulator shares the CPU
    with Bus(port, BAUD, default_model="xh430-w210", return_delay_us=0.0,
             timeout_margin_s=DRIVER_MARGIN_S) as bus:
        def once() -> bool:
            try:
                bus.sync_read(IDS, Reg.PRESENT_POSITION)
                return True
            except DxlError:
                return False

        return _rate(once, seconds)


def run(seconds: float) -> list[tuple[str, str, float, int]]:
    rows = []
    for label, extra in (("pty, no wire timing", ()), ("--wire-timing 1 Mbps", ("--wire-timing",))):
        emu = EmulatorProcess(*extra)
        try:
            _zero_return_delay(emu.port)
            rate, fails = bench_sdk(emu.port, seconds)
            rows.append((label, "dynamixel-sdk 4.1", rate, fails))
            res = bench_driver(emu.port, seconds)
            if res is not None:
                rows.append((label, "driver.bus.Bus", *res))
        finally:
            emu.close()
    return rows


def render(rows, seconds: float) -> str:
    nbytes, limit = wire_limit_rtps()
    lines = [
        SECTION, "",
        f"{dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC; `nproc` = {os.cpu_count()}; "
        f"CPU {cpu_model()}; Python {platform.python_version()}; `bench/bench_emulator.py` "
        f"({seconds:g} s per row).",
        "",
        "8-servo Sync Read of Present Position (4 bytes, IDs 1-8), Return Delay Time 0, "
        "`swerve emulate` in its own process, client in this one.",
        "",
        "| line | client | round trips/s | failed |",
        "|---|---|---:|---:|",
    ]
    for label, client, rate, fails in rows:
        lines.append(f"| {label} | {client} | {rate:.0f} | {fails} |")
    by_line: dict[str, dict[str, float]] = {}
    for label, client, rate, _ in rows:
        by_line.setdefault(label, {})[client] = rate
    lines.append("")
    for label, rates in by_line.items():
        if len(rates) == 2:
            sdk, ours = rates["dynamixel-sdk 4.1"], rates["driver.bus.Bus"]
            lines.append(f"- {label}: driver / SDK = **{ours / sdk:.2f}**"
                         + (f"; driver at {ours / limit:.0%} of the wire limit" if label.startswith("--wire") else ""))
    lines += [
        "",
        f"Wire-time limit at 1 Mbps: {nbytes} bytes per round trip (22 instruction + 8 x 15 status) "
        f"x 10 bit = {nbytes * 10 / BAUD * 1e3:.2f} ms -> **{limit:.0f} round trips/s** (no return "
        "delay, no USB latency). With the servo default Return Delay Time (500 us each) the limit "
        f"is {wire_limit_rtps(return_delay_s=500e-6)[1]:.0f}/s.",
        "The SDK polls a non-blocking port (busy-wait) and shares 2 cores with the emulator; "
        f"the driver blocks in `select` (run with `timeout_margin_s={DRIVER_MARGIN_S}`). "
        "Failed = round trips that timed out (counted in the rate).",
        "",
    ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring time per row")
    ap.add_argument("--no-write", action="store_true", help="print only, do not edit BENCHMARKS.md")
    args = ap.parse_args()
    text = render(run(args.seconds), args.seconds)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
