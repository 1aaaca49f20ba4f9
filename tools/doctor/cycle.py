"""The timed read/write cycle: the loop's Sync Read and Bulk Write, timed on the host, against
the bytes' wire time and the control period."""
from __future__ import annotations

import statistics
import time

from swerve.driver import packets as pk
from swerve.driver.bus import STATUS_OVERHEAD, Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import CorruptPacketError, DxlTimeoutError
from swerve.driver.robot_config import RobotConfig
from swerve.driver.transport import BITS_PER_BYTE
from swerve.tools.doctor.report import FAIL, PASS, WARN, Check

#: Control period the timed read/write cycle is judged against, s (the paper's 62.5 Hz).
DEFAULT_PERIOD_S = 0.016


def wire_time_s(cfg: RobotConfig, baud: int) -> float:
    """Shortest possible time of one control cycle at ``baud``: the Sync Read request, eight
    replies of 10 bytes with their return delays, and the Bulk Write of eight goals, s."""
    ids = list(cfg.drive_ids + cfg.steer_ids)
    table = cfg.table
    first, length = table.span(Reg.PRESENT_CURRENT, Reg.PRESENT_POSITION)
    req = len(pk.sync_read(first, length, ids).encode())
    replies = len(ids) * (STATUS_OVERHEAD + length)
    vel, pos = table[Reg.GOAL_VELOCITY], table[Reg.GOAL_POSITION]
    entries = [(i, vel.address, bytes(vel.size)) for i in cfg.drive_ids]
    entries += [(i, pos.address, bytes(pos.size)) for i in cfg.steer_ids]
    write = len(pk.bulk_write(entries).encode())
    return ((req + replies + write) * BITS_PER_BYTE / baud
            + len(ids) * cfg.link.return_delay_us * 1e-6)


def timed_cycle(cfg: RobotConfig, bus: Bus, *, cycles: int = 200,
                period_s: float = DEFAULT_PERIOD_S) -> tuple[Check, dict]:
    """Time ``cycles`` read/write cycles as the loop does them: one Sync Read of present
    current/velocity/position and one Bulk Write of zero wheel speed and the present steering
    position (nothing moves). Compares median and p99 with the wire limit and the period."""
    ids = list(cfg.drive_ids + cfg.steer_ids)
    pos = bus.sync_read(cfg.steer_ids, Reg.PRESENT_POSITION)
    items = {i: {Reg.GOAL_VELOCITY: 0} for i in cfg.drive_ids}
    items.update({i: {Reg.GOAL_POSITION: pos[i][Reg.PRESENT_POSITION]} for i in cfg.steer_ids})
    times, failed = [], 0
    for _ in range(cycles):
        t0 = time.perf_counter()
        try:
            bus.sync_read(ids, Reg.PRESENT_CURRENT, Reg.PRESENT_POSITION)
            bus.bulk_write(items)
        except (DxlTimeoutError, CorruptPacketError):
            failed += 1
            continue
        times.append(time.perf_counter() - t0)
    wire = wire_time_s(cfg, bus.baud)
    if not times:
        return Check("read/write cycle", FAIL, f"all {cycles} cycles failed",
                     "check the cable and the baud rate"), {}
    times.sort()
    med = statistics.median(times)
    p99 = times[min(len(times) - 1, int(0.99 * len(times)))]
    data = {"cycles": cycles, "failed": failed, "median_s": med, "p99_s": p99, "max_s": times[-1],
            "wire_s": wire, "period_s": period_s, "baud": bus.baud}
    detail = (f"median {med * 1e3:.2f} ms, p99 {p99 * 1e3:.2f} ms over {cycles} cycles; wire limit "
              f"{wire * 1e3:.2f} ms at {bus.baud} bps; period {period_s * 1e3:.0f} ms")
    if failed:
        return Check("read/write cycle", FAIL, f"{failed} of {cycles} cycles failed; {detail}",
                     "check the cable, termination and the latency timer"), data
    if p99 > 0.5 * period_s:
        return Check("read/write cycle", WARN, f"p99 above half the period; {detail}",
                     "set the latency timer to 1 ms, Return Delay 0, or a higher baud rate"), data
    return Check("read/write cycle", PASS, detail), data
