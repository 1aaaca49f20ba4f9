"""Each servo's health: latched Hardware Error Status (70) bits, input voltage against Min/Max
Voltage Limit (34/32), temperature against Temperature Limit (31) (e-Manual, X series)."""
from __future__ import annotations

import time

from swerve.driver.bus import Bus
from swerve.driver.control_table import HardwareError, Reg
from swerve.driver.errors import CorruptPacketError, DxlTimeoutError
from swerve.driver.robot_config import RobotConfig
from swerve.tools.doctor.report import FAIL, PASS, WARN, Check, DoctorReport

#: Temperature margin below Temperature Limit that is reported as a warning, degC.
TEMPERATURE_MARGIN_C = 10.0


def read_all(bus: Bus, ids: list[int], reg: Reg) -> dict[int, int]:
    """``{id: raw}`` of one item read from each servo."""
    return {i: bus.read(i, reg) for i in ids}


def check_health(cfg: RobotConfig, bus: Bus, ids: list[int], *, fix: bool, report: DoctorReport) -> list[int]:
    """Hardware Error Status, input voltage and temperature of each servo.

    Returns the IDs without a latched hardware error: a servo with one answers every read
    with the alert bit (the driver raises), so the later checks read only the others.
    """
    table = cfg.table
    volt_r = table[Reg.PRESENT_INPUT_VOLTAGE]
    hw = {i: bus.hardware_error(i) for i in ids}
    bad_hw = {i: b for i, b in hw.items() if b}
    if bad_hw and fix:
        for i in sorted(bad_hw):
            bus.reboot(i)
            report.fixed.append(f"rebooted ID {i} to clear {HardwareError.describe(bad_hw[i])}")
        time.sleep(0.1)
        hw = {i: _wait_answer(bus, i) for i in ids}
        bad_hw = {i: b for i, b in hw.items() if b}
    if bad_hw:
        lines = []
        for i, bits in sorted(bad_hw.items()):
            lines.append(f"ID {i}: 0x{bits:02X} ({HardwareError.explain(bits)})")
        report.checks.append(Check("hardware errors", FAIL, "; ".join(lines),
                                   "remove the cause, then reboot the servo: swerve doctor --fix"))
    else:
        report.checks.append(Check("hardware errors", PASS, "none latched"))
    ids = [i for i in ids if i not in bad_hw]
    if not ids:
        return ids
    volts = {i: volt_r.to_si(v) for i, v in read_all(bus, ids, Reg.PRESENT_INPUT_VOLTAGE).items()}
    lo = {i: table[Reg.MIN_VOLTAGE_LIMIT].to_si(v) for i, v in read_all(bus, ids, Reg.MIN_VOLTAGE_LIMIT).items()}
    hi = {i: table[Reg.MAX_VOLTAGE_LIMIT].to_si(v) for i, v in read_all(bus, ids, Reg.MAX_VOLTAGE_LIMIT).items()}
    out = {i: v for i, v in volts.items() if not lo[i] <= v <= hi[i]}
    span = f"{min(volts.values()):.1f}-{max(volts.values()):.1f} V"
    if out:
        report.checks.append(Check(
            "input voltage", FAIL, "outside Min/Max Voltage Limit: "
            + ", ".join(f"ID {i}: {v:.1f} V (limits {lo[i]:.1f}-{hi[i]:.1f} V)" for i, v in sorted(out.items())),
            "check the supply (12 V for XH430) and its cable; a sagging supply trips the input voltage error"))
    else:
        report.checks.append(Check("input voltage", PASS, f"{span}, within the servos' limits"))

    temp_r = table[Reg.PRESENT_TEMPERATURE]
    temps = {i: temp_r.to_si(v) for i, v in read_all(bus, ids, Reg.PRESENT_TEMPERATURE).items()}
    limit = {i: table[Reg.TEMPERATURE_LIMIT].to_si(v) for i, v in read_all(bus, ids, Reg.TEMPERATURE_LIMIT).items()}
    hot = {i: t for i, t in temps.items() if t >= limit[i] - TEMPERATURE_MARGIN_C}
    if hot:
        worst = FAIL if any(t >= limit[i] for i, t in hot.items()) else WARN
        report.checks.append(Check(
            "temperature", worst, ", ".join(f"ID {i}: {t:.0f} C (limit {limit[i]:.0f} C)"
                                            for i, t in sorted(hot.items())),
            "let the servos cool with the torque off; check for a stalled wheel or steering end stop"))
    else:
        report.checks.append(Check("temperature", PASS, f"{min(temps.values()):.0f}-{max(temps.values()):.0f} C"))
    return ids


def _wait_answer(bus: Bus, id_: int, timeout_s: float = 3.0) -> int:
    """Hardware Error Status of ``id_`` once it answers again after a reboot."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            return bus.hardware_error(id_)
        except (DxlTimeoutError, CorruptPacketError):
            if time.monotonic() > end:
                raise
            time.sleep(0.05)
