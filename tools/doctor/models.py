"""Model number and firmware of every servo found, against the robot file's control table."""
from __future__ import annotations

from swerve.driver.bus import PingResult
from swerve.driver.robot_config import RobotConfig
from swerve.tools.doctor.report import FAIL, PASS, WARN, Check, DoctorReport

#: Oldest firmware the shipped control tables and Fast Sync Read are written for.
MIN_FIRMWARE = 45


def check_models(cfg: RobotConfig, found: dict[int, PingResult], report: DoctorReport) -> None:
    """Model number and firmware of every found servo against the shipped control table."""
    table = cfg.table
    wrong = {i: r.model for i, r in found.items() if r.model_number != table.model_number}
    if wrong:
        report.checks.append(Check(
            "model", FAIL, f"robot file says {table.model} ({table.model_number}); servos report "
            + ", ".join(f"ID {i}: {m}" for i, m in sorted(wrong.items())),
            "set model: in the robot file to the servos' model (a table in configs/models/)"))
    else:
        report.checks.append(Check("model", PASS, f"{len(found)} x {table.model}"))
    old = {i: r.firmware for i, r in found.items() if r.firmware < MIN_FIRMWARE}
    if old:
        report.checks.append(Check(
            "firmware", WARN, "firmware older than the shipped tables (>= "
            f"{MIN_FIRMWARE}): " + ", ".join(f"ID {i}: v{f}" for i, f in sorted(old.items())),
            "update the firmware with DYNAMIXEL Wizard 2.0 (Fast Sync Read needs >= 45)"))
    else:
        fws = sorted({r.firmware for r in found.values()})
        report.checks.append(Check("firmware", PASS, "v" + ", v".join(map(str, fws))))
