"""``swerve doctor``: check a robot's servo bus against its robot file, one line per check.

Each :class:`Check` is ``pass``, ``warn`` or ``fail`` and carries the one-line fix; a report
fails (exit 1) only when a check fails. The checks use the driver
(:class:`~swerve.driver.bus.Bus`, its Ping/scan and Sync Read) and never speak the protocol
themselves; one module per kind of check::

    report = diagnose(load_robot_config(path), port)            # read-only
    report = diagnose(cfg, port, fix=True)                      # also repairs what it can
    print(report.exit_code, [c.line() for c in report.checks])
"""
from swerve.tools.doctor.checklist import diagnose
from swerve.tools.doctor.cycle import DEFAULT_PERIOD_S, timed_cycle, wire_time_s
from swerve.tools.doctor.health import check_health
from swerve.tools.doctor.latency import (UDEV_RULE, UDEV_RULE_PATH, EmulatedLatencyTimer, LatencyTimer,
                                         SysfsLatencyTimer, check_latency)
from swerve.tools.doctor.models import MIN_FIRMWARE, check_models
from swerve.tools.doctor.presence import Location, check_presence, locate_all, move_servo, ping_ids, plan_moves
from swerve.tools.doctor.report import EXIT_FAILED, EXIT_OK, FAIL, PASS, WARN, Check, DoctorReport
from swerve.tools.doctor.settings import check_settings, wanted_settings

__all__ = ["Check", "DEFAULT_PERIOD_S", "DoctorReport", "EXIT_FAILED", "EXIT_OK", "EmulatedLatencyTimer", "FAIL",
           "LatencyTimer", "Location", "MIN_FIRMWARE", "PASS", "SysfsLatencyTimer", "UDEV_RULE", "UDEV_RULE_PATH",
           "WARN", "check_health", "check_latency", "check_models", "check_presence", "check_settings", "diagnose",
           "locate_all", "move_servo", "ping_ids", "plan_moves", "timed_cycle", "wanted_settings", "wire_time_s"]
