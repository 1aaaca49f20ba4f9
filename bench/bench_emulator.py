"""Round trips per second of an 8-servo Sync Read over the emulator's pty.

Runs ``swerve emulate`` in a separate process (as a user would), sets every servo's Return
Delay Time to 0 (what ``configs/robot.yaml`` asks for), then for a few seconds each times
Sync Read of Present Position (4 bytes) from IDs 1-8 with dynamixel-sdk 4.1 (unmodified) and
with the project's ``driver.bus.Bus``, one after the other against the same emulator process,
without and with ``--wire-timing`` at 1 Mbps, ``--repeat`` times. The wire-time limit is
computed from the byte counts (10 bits per byte, no gaps). Per row it also records the CPU
time per round trip of the client (this process, ``time.process_time``) and of the emulator
process (``/proc/PID/stat``, 10 ms ticks), and the 1-minute load average when the row started.
Every round runs on the machine as it is (``idle``); ``--pm-qos`` measures it again while
holding a PM QoS CPU latency request of 0 us (idle CPUs poll instead of halting; needs root),
and ``--burners N`` again beside N processes that spin in pure Python (a busy machine), both
for the two clients alike. A polling client gains most on an idle machine, whose idle CPUs
halt (waking one costs a hypervisor exit on a VM), and loses most on a busy one, where its
polling takes turns on the cores with the emulator.

    .venv/bin/python bench/bench_emulator.py [--seconds 3] [--repeat 3] [--pm-qos] [--burners N] [--no-write]

Writes the section "## Emulator bus" of BENCHMARKS.md (other sections untouched).
"""
from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import os
import platform
import signal
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchutil import CPU_DMA_LATENCY, CpuLatencyRequest, check_cpu_latency_request, cpu_model, write_section  # noqa: E402
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


@dataclass(frozen=True)
class Row:
    """One client measured for ``seconds`` against one emulator."""

    line: str                  # "pty, no wire timing" or "--wire-timing 1 Mbps"
    client: str
    rate_hz: float             # round trips per second (failed ones included)
    fails: int                 # round trips that timed out
    client_cpu_us: float       # CPU of this process per round trip, us
    emulator_cpu_us: float     # CPU of the emulator process per round trip, us
    load_1min: float           # 1-minute load average when the row started
    machine: str = "idle"      # "idle", "idle CPUs poll" (PM QoS 0 us) or "N burners"


def _process_cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (all its threads)."""
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rate(fn, seconds: float, emulator_pid: int) -> tuple[float, int, float, float]:
    """Calls per second of ``fn`` (returns False on failure), the failure count, and CPU us per
    call of this process and of the emulator."""
    for _ in range(20):
        fn()                                   # warm up
    n = fails = 0
    cpu0, emu0 = time.process_time(), _process_cpu_s(emulator_pid)
    t0 = time.perf_counter()
    deadline = t0 + seconds
    while time.perf_counter() < deadline:
        if not fn():
            fails += 1
        n += 1
    elapsed = time.perf_counter() - t0
    cpu, emu = time.process_time() - cpu0, _process_cpu_s(emulator_pid) - emu0
    return n / elapsed, fails, cpu / n * 1e6, emu / n * 1e6


def bench_sdk(port: str, seconds: float, emulator_pid: int) -> tuple[float, int, float, float]:
    import dynamixel_sdk as sdk

    ph, pk = sdk.PortHandler(port), sdk.PacketHandler(2.0)
    ph.openPort()
    ph.setBaudRate(BAUD)
    group = sdk.GroupSyncRead(ph, pk, ADDRESS, LENGTH)
    for i in IDS:
        group.addParam(i)
    try:
        return _rate(lambda: group.txRxPacket() == sdk.COMM_SUCCESS, seconds, emulator_pid)
    finally:
        ph.closePort()


def bench_driver(port: str, seconds: float, emulator_pid: int) -> tuple[float, int, float, float] | None:
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

        return _rate(once, seconds, emulator_pid)


SDK, DRIVER = "dynamixel-sdk 4.1", "driver.bus.Bus"
LINES = (("pty, no wire timing", ()), ("--wire-timing 1 Mbps", ("--wire-timing",)))
IDLE, POLLING = "idle", "idle CPUs poll"


@contextlib.contextmanager
def burners(n: int):
    """``n`` processes spinning in pure Python for the duration (a busy machine)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def conditions(pm_qos: bool, n_burners: int) -> list[tuple[str, contextlib.AbstractContextManager]]:
    """The machine states each round is measured in: ``(name, context manager factory)``."""
    out = [(IDLE, contextlib.nullcontext)]
    if pm_qos:
        out.append((POLLING, lambda: CpuLatencyRequest(0)))
    if n_burners:
        out.append((f"{n_burners} burner{'s' if n_burners > 1 else ''}", lambda: burners(n_burners)))
    return out


def _round(seconds: float, machine: str) -> list[Row]:
    """Per line one emulator process, the SDK then the driver."""
    rows = []
    for label, extra in LINES:
        emu = EmulatorProcess(*extra)
        try:
            _zero_return_delay(emu.port)
            for client, bench in ((SDK, bench_sdk), (DRIVER, bench_driver)):
                load = os.getloadavg()[0]
                res = bench(emu.port, seconds, emu.proc.pid)
                if res is not None:
                    rows.append(Row(label, client, *res, load, machine))
        finally:
            emu.close()
    return rows


def run(seconds: float, repeat: int = 1, pm_qos: bool = False, n_burners: int = 0) -> list[Row]:
    """``repeat`` rounds, each measured in every machine state of :func:`conditions`."""
    rows = []
    for _ in range(repeat):
        for machine, state in conditions(pm_qos, n_burners):
            with state():
                rows += _round(seconds, machine)
    return rows


def render(rows: list[Row], seconds: float, repeat: int, pm_qos: bool = False, n_burners: int = 0) -> str:
    nbytes, limit = wire_limit_rtps()
    machines = [m for m, _ in conditions(pm_qos, n_burners)]
    lines = [
        SECTION, "",
        f"{dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC; `nproc` = {os.cpu_count()}; "
        f"CPU {cpu_model()}; Python {platform.python_version()}; `bench/bench_emulator.py "
        f"--seconds {seconds:g} --repeat {repeat}{' --pm-qos' if pm_qos else ''}"
        f"{f' --burners {n_burners}' if n_burners else ''}`.",
        "",
        "8-servo Sync Read of Present Position (4 bytes, IDs 1-8), Return Delay Time 0, "
        "`swerve emulate` in its own process, client in this one; in each round the SDK and the "
        "driver take turns against the same emulator process. CPU per round trip: the client "
        "process and the emulator process; load: 1-minute load average when the row started. "
        "Machine: `idle` is the machine as it is (its idle CPUs halt)"
        + (f"; `idle CPUs poll` holds a PM QoS CPU latency request of 0 us (`{CPU_DMA_LATENCY}`), "
           "so an idle CPU spins in the kernel instead of halting" if pm_qos else "")
        + ("; `burners` runs that many processes spinning in pure Python beside the bench"
           if n_burners else "") + ".",
        "",
        "| round | machine | line | client | round trips/s | failed | client CPU us/rt | emulator CPU us/rt | load |",
        "|---:|---|---|---|---:|---:|---:|---:|---:|",
    ]
    per_round = max(1, len(rows) // repeat)
    for k, r in enumerate(rows):
        lines.append(f"| {k // per_round + 1} | {r.machine} | {r.line} | {r.client} | {r.rate_hz:.0f} | {r.fails} | "
                     f"{r.client_cpu_us:.0f} | {r.emulator_cpu_us:.0f} | {r.load_1min:.2f} |")
    lines.append("")
    for machine in machines:
        for label, _ in LINES:
            mine = [r for r in rows if r.line == label and r.machine == machine]
            rates = {c: statistics.median(r.rate_hz for r in mine if r.client == c)
                     for c in (SDK, DRIVER) if any(r.client == c for r in mine)}
            cpu = {c: statistics.median(r.client_cpu_us for r in mine if r.client == c) for c in rates}
            if len(rates) == 2:
                lines.append(f"- {label}, {machine}, medians of {repeat}: driver {rates[DRIVER]:.0f} vs "
                             f"SDK {rates[SDK]:.0f} round trips/s, driver / SDK = "
                             f"**{rates[DRIVER] / rates[SDK]:.2f}**; client CPU "
                             f"{cpu[DRIVER]:.0f} vs {cpu[SDK]:.0f} us per round trip"
                             + (f"; driver at **{rates[DRIVER] / limit:.0%}** of the wire limit, SDK at "
                                f"{rates[SDK] / limit:.0%}" if label.startswith("--wire") else ""))
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
    ap.add_argument("--repeat", type=int, default=3, help="rounds (each: both lines, both clients)")
    ap.add_argument("--pm-qos", action="store_true",
                    help="measure every round again with idle CPUs polling (PM QoS 0 us; root)")
    ap.add_argument("--burners", type=int, default=0, metavar="N",
                    help="measure every round again beside N processes spinning in Python")
    ap.add_argument("--no-write", action="store_true", help="print only, do not edit BENCHMARKS.md")
    args = ap.parse_args()
    if args.repeat < 1 or not args.seconds > 0 or args.burners < 0:
        ap.error("--repeat must be >= 1, --seconds > 0 and --burners >= 0")
    if args.pm_qos:
        check_cpu_latency_request(ap)
    rows = run(args.seconds, args.repeat, args.pm_qos, args.burners)
    text = render(rows, args.seconds, args.repeat, args.pm_qos, args.burners)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
