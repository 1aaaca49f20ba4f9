"""The whole checklist, in order: latency timer, servos present, model and firmware, health,
settings, timed read/write cycle (each kind in its own module of :mod:`swerve.tools.doctor`)."""
from __future__ import annotations

from typing import Iterable

from swerve.driver.bus import Bus
from swerve.driver.control_table import SCAN_BAUDS_BPS
from swerve.driver.robot_config import RobotConfig
from swerve.tools.doctor.cycle import timed_cycle
from swerve.tools.doctor.health import check_health
from swerve.tools.doctor.latency import LatencyTimer, SysfsLatencyTimer, check_latency
from swerve.tools.doctor.models import check_models
from swerve.tools.doctor.presence import check_presence
from swerve.tools.doctor.report import FAIL, Check, DoctorReport
from swerve.tools.doctor.settings import check_settings


def diagnose(cfg: RobotConfig, port: str, *, fix: bool = False, margin_s: float = 0.002,
             cycles: int = 200, scan_bauds: Iterable[int] = SCAN_BAUDS_BPS,
             latency: LatencyTimer | None = None) -> DoctorReport:
    """Run every check on ``port`` against ``cfg``; with ``fix`` repair what can be repaired.

    ``latency``: the adapter's latency timer (default: ``port``'s in sysfs; the emulator passes
    its own adapter's, :class:`~swerve.tools.doctor.latency.EmulatedLatencyTimer`). Later checks
    need the servos: when some are missing only the ones found are checked and the timed cycle
    is skipped (reported as a failure).
    """
    report = DoctorReport(port)
    check, done = check_latency(latency if latency is not None else SysfsLatencyTimer(port), fix=fix)
    report.checks.append(check)
    if done:
        report.fixed.append(done)
    found = check_presence(cfg, port, fix=fix, margin_s=margin_s, report=report, scan_bauds=scan_bauds)
    if not found:
        return report
    check_models(cfg, found, report)
    ids = sorted(found)
    with Bus(port, cfg.link.baud, timeout_margin_s=margin_s, default_model=cfg.model) as bus:
        healthy = check_health(cfg, bus, ids, fix=fix, report=report)
        if healthy:
            check_settings(cfg, bus, healthy, fix=fix, report=report)
        if len(healthy) == len(cfg.drive_ids + cfg.steer_ids):
            check, report.timing = timed_cycle(cfg, bus, cycles=cycles)
            report.checks.append(check)
        else:
            report.checks.append(Check("read/write cycle", FAIL,
                                       "skipped: not every servo answers without a hardware alert",
                                       "fix the servos above first"))
    return report
