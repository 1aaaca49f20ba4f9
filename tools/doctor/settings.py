"""The servos' settings against the robot file: Operating Mode and Return Delay Time (EEPROM),
gains (RAM) and the Bus Watchdog (98)."""
from __future__ import annotations

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import RobotConfig
from swerve.driver.wheelset import WheelSet
from swerve.tools.doctor.health import read_all
from swerve.tools.doctor.report import PASS, WARN, Check, DoctorReport, ids_text


def wanted_settings(cfg: RobotConfig) -> dict[int, dict[str, int]]:
    """``{id: {register: raw}}``: what the robot file wants in each servo (modes, delay, gains)."""
    table = cfg.table
    rdt = table[Reg.RETURN_DELAY_TIME].from_si(cfg.link.return_delay_us * 1e-6)
    out: dict[int, dict[str, int]] = {}
    for ids, group in ((cfg.drive_ids, cfg.drive), (cfg.steer_ids, cfg.steering)):
        for i in ids:
            out[i] = {Reg.OPERATING_MODE.value: group.operating_mode, Reg.RETURN_DELAY_TIME.value: rdt,
                      **{str(k): int(v) for k, v in group.gains.items()}}
    return out


def check_settings(cfg: RobotConfig, bus: Bus, ids: list[int], *, fix: bool, report: DoctorReport) -> None:
    """Operating Mode, Return Delay, Bus Watchdog and gains against the robot file.

    Gains are RAM items: after power-up they hold the e-Manual defaults and ``swerve run``
    writes the file's at start, so the defaults pass (with a note); any other value warns.
    EEPROM items (mode, return delay) that differ pass, reported as what ``swerve run`` will
    set (it writes them with the torque off before it moves); ``fix`` writes everything now with
    :meth:`WheelSet.configure`.
    """
    table = cfg.table
    want = wanted_settings(cfg)

    def diff() -> tuple[dict, dict]:
        eeprom, ram = {}, {}
        for i in ids:
            for name, raw in want[i].items():
                got = bus.read(i, name)
                if got == raw:
                    continue
                (eeprom if table[name].eeprom else ram)[(i, name)] = (got, raw)
        return eeprom, ram

    eeprom, ram = diff()
    if fix and (eeprom or ram) and set(ids) == set(want):
        WheelSet(bus, cfg).configure()
        bus.sync_write(Reg.BUS_WATCHDOG, {i: 0 for i in ids})   # armed by swerve run, not at rest
        report.fixed.append("wrote operating modes, return delay and gains of the robot file (torque off)")
        eeprom, ram = diff()
    if eeprom:        # WheelSet.configure() writes them with the torque off before the run moves
        report.checks.append(Check("EEPROM settings", PASS, "swerve run sets them before it moves: "
                                   + _diff_text(eeprom, changes=True)))
    else:
        report.checks.append(Check("EEPROM settings", PASS, "operating modes and return delay as in the robot file"))
    non_default = {k: v for k, v in ram.items() if v[0] != table[k[1]].default}
    if non_default:
        report.checks.append(Check("gains", WARN, _diff_text(non_default),
                                   "swerve doctor --fix writes the robot file's gains"))
    elif ram:
        report.checks.append(Check("gains", PASS, "power-up defaults; swerve run writes the robot file's"))
    else:
        report.checks.append(Check("gains", PASS, "as in the robot file"))
    wd = read_all(bus, ids, Reg.BUS_WATCHDOG)
    tripped = [i for i, v in wd.items() if v < 0]
    wd_raw = table[Reg.BUS_WATCHDOG].from_si(cfg.bus_watchdog_s)
    odd = {i: v for i, v in wd.items() if v not in (0, wd_raw) and v >= 0}
    if tripped or odd:
        text = ", ".join([f"ID {i}: fired (-1)" for i in tripped]
                         + [f"ID {i}: {v} x 20 ms" for i, v in odd.items()])
        report.checks.append(Check("bus watchdog", WARN, text,
                                   "swerve doctor --fix clears it (write 0); swerve run arms it"))
    else:
        report.checks.append(Check("bus watchdog", PASS,
                                   f"off at rest; swerve run arms {cfg.bus_watchdog_s * 1e3:.0f} ms"))


def _diff_text(items: dict, changes: bool = False) -> str:
    """``{(id, register): (got, wanted)}`` as one phrase per register and value pair:
    ``name GOT on ID 1,2 (file: WANTED)``, or with ``changes`` ``name GOT -> WANTED on ID 1,2``."""
    groups: dict[tuple[str, int, int], list[int]] = {}
    for (i, name), (got, raw) in sorted(items.items()):
        groups.setdefault((name, got, raw), []).append(i)
    if changes:
        return "; ".join(f"{name} {got} -> {raw} on ID {ids_text(ids)}" for (name, got, raw), ids in groups.items())
    return "; ".join(f"{name} {got} on ID {ids_text(ids)} (file: {raw})" for (name, got, raw), ids in groups.items())
