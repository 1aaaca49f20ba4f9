"""``swerve doctor``: check a robot's servo bus against its robot file, one line per check.

Each :class:`Check` is ``pass``, ``warn`` or ``fail`` and carries the one-line fix. The checks
use the driver (:class:`~swerve.driver.bus.Bus`, its Ping/scan and Sync Read) and never speak
the protocol themselves::

    report = diagnose(load_robot_config(path), port)            # read-only
    report = diagnose(cfg, port, fix=True)                      # also repairs what it can
    print(report.ok, [c.line() for c in report.checks])

Facts from the ROBOTIS e-Manual (XH430-W210, X-series control table): Baud Rate (8) values,
Hardware Error Status (70) bits, Input Voltage limits (32/34), Temperature Limit (31), Bus
Watchdog (98; -1 after it fired). ID and Baud Rate are EEPROM items: written with the torque
off, and the new ID/baud takes effect after the status reply.
"""
from __future__ import annotations

import os
import statistics
import time
from dataclasses import asdict, dataclass, field
from typing import Iterable

from swerve.driver import packets as pk
from swerve.driver.bus import STATUS_OVERHEAD, Bus, PingResult
from swerve.driver.control_table import HardwareError, Reg, baud_index
from swerve.driver.errors import CorruptPacketError, DxlError, DxlTimeoutError
from swerve.driver.robot_config import RobotConfig
from swerve.driver.transport import (BITS_PER_BYTE, STANDARD_BAUDS, latency_fix_command,
                                     latency_timer_ms)

PASS, WARN, FAIL = "pass", "warn", "fail"

#: udev rule that sets every FTDI adapter's latency timer to 1 ms when it is plugged in.
UDEV_RULE = ('ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", '
             'ATTR{latency_timer}="1"')
UDEV_RULE_PATH = "/etc/udev/rules.d/99-u2d2-latency.rules"

#: What each Hardware Error Status bit means (e-Manual, X series, address 70).
HARDWARE_ERROR_MEANING = {
    HardwareError.INPUT_VOLTAGE: "input voltage: the supply is outside Min/Max Voltage Limit",
    HardwareError.OVERHEATING: "overheating: the internal temperature exceeded Temperature Limit",
    HardwareError.MOTOR_ENCODER: "motor encoder: the encoder malfunctioned",
    HardwareError.ELECTRICAL_SHOCK: "electrical shock: an electrical shock on the circuit, "
                                    "or too little power to drive the motor",
    HardwareError.OVERLOAD: "overload: a persistent load beyond the servo's maximum output",
}
#: Oldest firmware the shipped control tables and Fast Sync Read are written for.
MIN_FIRMWARE = 45
#: Temperature margin below Temperature Limit that is reported as a warning, degC.
TEMPERATURE_MARGIN_C = 10.0
#: Control period the timed read/write cycle is judged against, s (the paper's 62.5 Hz).
DEFAULT_PERIOD_S = 0.016


@dataclass(frozen=True)
class Check:
    """One line of the checklist: ``status`` is pass / warn / fail; ``fix`` the one-line remedy."""

    name: str
    status: str
    detail: str
    fix: str = ""

    def line(self) -> str:
        text = f"[{self.status}] {self.name}: {self.detail}"
        return text + (f"\n       fix: {self.fix}" if self.fix and self.status != PASS else "")


@dataclass
class Location:
    """Where a servo answered: ``baud`` bps and its Ping result."""

    baud: int
    ping: PingResult


@dataclass
class DoctorReport:
    """All checks, plus what ``fix=True`` changed (``fixed``: one sentence per action)."""

    port: str
    checks: list[Check] = field(default_factory=list)
    fixed: list[str] = field(default_factory=list)
    timing: dict | None = None

    @property
    def ok(self) -> bool:
        """True only when every check passed."""
        return all(c.status == PASS for c in self.checks)

    def as_dict(self) -> dict:
        return {"port": self.port, "ok": self.ok, "checks": [asdict(c) for c in self.checks],
                "fixed": list(self.fixed), "timing": self.timing}


# --- latency timer --------------------------------------------------------------------------

def check_latency(port: str, *, fix: bool = False, sysfs_root: str | None = None) -> tuple[Check, str | None]:
    """The USB-serial latency timer of ``port`` (1 ms wanted). Returns ``(check, fixed?)``."""
    kw = {} if sysfs_root is None else {"sysfs_root": sysfs_root}
    value = latency_timer_ms(port, warn=False, **kw)
    if value is None:
        return Check("latency timer", PASS, f"{port} is not a USB-serial adapter (no latency timer)"), None
    dev = os.path.basename(os.path.realpath(port))
    if value <= 1:
        return Check("latency timer", PASS, f"{dev}: {value} ms"), None
    msg = f"{dev}: {value} ms; every reply may wait that long (want 1 ms)"
    done = None
    if fix:
        path = os.path.join(sysfs_root or "/sys/bus/usb-serial/devices", dev, "latency_timer")
        try:
            with open(path, "w") as fh:
                fh.write("1\n")
        except OSError as exc:
            msg += f" (could not set it: {exc.strerror})"
        else:
            value = latency_timer_ms(port, warn=False, **kw) or value
            done = f"set the latency timer of {dev} to 1 ms (until the adapter is replugged)"
            if value <= 1:
                return Check("latency timer", PASS, f"{dev}: {value} ms"), done
    return Check("latency timer", WARN, msg,
                 f"{latency_fix_command(dev)}; to keep it, put '{UDEV_RULE}' in {UDEV_RULE_PATH}"), done


# --- finding the servos -----------------------------------------------------------------------

def _open(port: str, baud: int, margin_s: float) -> Bus:
    return Bus(port, baud, timeout_margin_s=margin_s)


def ping_ids(port: str, baud: int, ids: Iterable[int], margin_s: float) -> dict[int, PingResult]:
    """Ping each of ``ids`` at ``baud``; ``{id: PingResult}`` of those that answered."""
    out = {}
    with _open(port, baud, margin_s) as bus:
        for i in ids:
            try:
                out[i] = bus.ping(i)
            except (DxlTimeoutError, CorruptPacketError):
                pass
    return out


def locate_all(port: str, bauds: Iterable[int] = STANDARD_BAUDS, ids: Iterable[int] = range(0, 253),
               margin_s: float = 0.002) -> list[Location]:
    """Every servo on the bus at every baud in ``bauds``, by one Broadcast Ping per baud.

    Protocol 2.0 servos answer a Broadcast Ping in turn by ID, so one window per baud finds
    them all (a unicast ping of 253 IDs would take 253 timeouts per baud).
    """
    found = []
    for baud in bauds:
        with _open(port, baud, margin_s) as bus:
            found += [Location(baud, r) for r in bus.broadcast_ping(ids).values()]
    return found


def plan_moves(cfg: RobotConfig, missing: list[int], strays: list[Location]) -> dict[int, Location]:
    """Which stray servo should become which missing ID: ``{target_id: location}``.

    A stray whose ID is one of the missing (only its baud is wrong) keeps that ID; if exactly
    one ID and one servo of the configured model remain, that servo takes it. Anything more
    ambiguous is left to the user (connect one new servo at a time).
    """
    model = cfg.table.model_number
    moves: dict[int, Location] = {}
    left = [s for s in strays if s.ping.model_number == model]
    for s in list(left):
        if s.ping.id in missing and s.ping.id not in moves:
            moves[s.ping.id] = s
            left.remove(s)
    rest = [i for i in missing if i not in moves]
    if len(rest) == 1 and len(left) == 1:
        moves[rest[0]] = left[0]
    return moves


def move_servo(port: str, src: Location, target_id: int, target_baud: int, margin_s: float,
               occupied: set[tuple[int, int]]) -> str:
    """Torque off, change ID then Baud Rate, and confirm with a Ping at the new place.

    ``occupied``: ``(baud, id)`` pairs already taken (a move onto one is refused). Returns
    one sentence; raises :class:`DxlError` when the servo is not at its new place.
    """
    old_id, old_baud = src.ping.id, src.baud
    if (old_baud, target_id) in occupied and target_id != old_id:
        raise DxlError(f"cannot give ID {target_id} to the servo at ID {old_id}, {old_baud} bps: "
                       f"another servo already has that ID at that baud")
    with _open(port, old_baud, margin_s) as bus:
        bus.write(old_id, Reg.TORQUE_ENABLE, 0)
        if target_id != old_id:
            bus.write(old_id, Reg.ID, target_id)
            bus.ping(target_id)
        if target_baud != old_baud:
            bus.write(target_id, Reg.BAUD_RATE, baud_index(target_baud))
    if target_baud != old_baud:
        time.sleep(0.05)        # the servo switches its UART after the reply
    with _open(port, target_baud, margin_s) as bus:
        try:
            bus.ping(target_id)
        except (DxlTimeoutError, CorruptPacketError):
            raise DxlError(f"the servo moved from ID {old_id} at {old_baud} bps did not answer as "
                           f"ID {target_id} at {target_baud} bps") from None
    return f"moved the servo at ID {old_id}, {old_baud} bps to ID {target_id}, {target_baud} bps (pinged)"


def check_presence(cfg: RobotConfig, port: str, *, fix: bool, margin_s: float,
                   report: DoctorReport, scan_bauds: Iterable[int] = STANDARD_BAUDS) -> dict[int, PingResult]:
    """Every ID of the robot file at the file's baud; else scan and say where each servo is."""
    want = list(cfg.drive_ids + cfg.steer_ids)
    baud = cfg.link.baud
    found = ping_ids(port, baud, want, margin_s)
    missing = [i for i in want if i not in found]
    if not missing:
        report.checks.append(Check("servos present", PASS,
                                   f"IDs {_ids(want)} answer at {baud} bps"))
        return found
    located = locate_all(port, scan_bauds, margin_s=margin_s)
    strays = [loc for loc in located if not (loc.baud == baud and loc.ping.id in want)]
    where = "; ".join(f"ID {s.ping.id} ({s.ping.model}) at {s.baud} bps" for s in strays) or "none"
    moves = plan_moves(cfg, missing, strays)
    if fix and moves:
        occupied = {(loc.baud, loc.ping.id) for loc in located}
        for target, src in sorted(moves.items()):
            report.fixed.append(move_servo(port, src, target, baud, margin_s, occupied))
        found = ping_ids(port, baud, want, margin_s)
        missing = [i for i in want if i not in found]
        if not missing:
            report.checks.append(Check("servos present", PASS,
                                       f"IDs {_ids(want)} answer at {baud} bps (after moving "
                                       f"{len(moves)} servo(s))"))
            return found
    plan = ", ".join(f"ID {s.ping.id} at {s.baud} bps -> ID {t} at {baud} bps"
                     for t, s in sorted(moves.items()))
    fix_text = (f"swerve doctor --fix moves {plan}" if moves else
                "connect the missing servos one at a time and run swerve doctor --fix; check power and "
                "cables")
    report.checks.append(Check(
        "servos present", FAIL,
        f"IDs {_ids(missing)} do not answer at {baud} bps; other servos found: {where}", fix_text))
    return found


def _ids(ids: Iterable[int]) -> str:
    return ",".join(map(str, ids))


# --- per-servo checks -------------------------------------------------------------------------

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


def _read_all(bus: Bus, ids: list[int], reg: Reg) -> dict[int, int]:
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
            meaning = "; ".join(m for b, m in HARDWARE_ERROR_MEANING.items() if bits & b)
            lines.append(f"ID {i}: 0x{bits:02X} ({meaning or 'unknown bits'})")
        report.checks.append(Check("hardware errors", FAIL, "; ".join(lines),
                                   "remove the cause, then reboot the servo: swerve doctor --fix"))
    else:
        report.checks.append(Check("hardware errors", PASS, "none latched"))
    ids = [i for i in ids if i not in bad_hw]
    if not ids:
        return ids
    volts = {i: volt_r.to_si(v) for i, v in _read_all(bus, ids, Reg.PRESENT_INPUT_VOLTAGE).items()}
    lo = {i: table[Reg.MIN_VOLTAGE_LIMIT].to_si(v) for i, v in _read_all(bus, ids, Reg.MIN_VOLTAGE_LIMIT).items()}
    hi = {i: table[Reg.MAX_VOLTAGE_LIMIT].to_si(v) for i, v in _read_all(bus, ids, Reg.MAX_VOLTAGE_LIMIT).items()}
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
    temps = {i: temp_r.to_si(v) for i, v in _read_all(bus, ids, Reg.PRESENT_TEMPERATURE).items()}
    limit = {i: table[Reg.TEMPERATURE_LIMIT].to_si(v) for i, v in _read_all(bus, ids, Reg.TEMPERATURE_LIMIT).items()}
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
    EEPROM items (mode, return delay) that differ warn; ``fix`` writes everything with
    :meth:`WheelSet.configure` (torque off).
    """
    from swerve.driver.wheelset import WheelSet

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
    for label, items in (("EEPROM settings", eeprom),):
        if items:
            report.checks.append(Check(label, WARN, _diff_text(items),
                                       "swerve doctor --fix writes them (swerve run does too, at start)"))
        else:
            report.checks.append(Check(label, PASS, "operating modes and return delay as in the robot file"))
    non_default = {k: v for k, v in ram.items() if v[0] != table[k[1]].default}
    if non_default:
        report.checks.append(Check("gains", WARN, _diff_text(non_default),
                                   "swerve doctor --fix writes the robot file's gains"))
    elif ram:
        report.checks.append(Check("gains", PASS, "power-up defaults; swerve run writes the robot file's"))
    else:
        report.checks.append(Check("gains", PASS, "as in the robot file"))
    wd = _read_all(bus, ids, Reg.BUS_WATCHDOG)
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


def _diff_text(items: dict) -> str:
    """``{(id, register): (got, wanted)}`` as one phrase per register and value pair."""
    groups: dict[tuple[str, int, int], list[int]] = {}
    for (i, name), (got, raw) in sorted(items.items()):
        groups.setdefault((name, got, raw), []).append(i)
    return "; ".join(f"{name} {got} on ID {_ids(ids)} (file: {raw})" for (name, got, raw), ids in groups.items())


# --- timed cycle ----------------------------------------------------------------------------

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


# --- the whole checklist --------------------------------------------------------------------

def diagnose(cfg: RobotConfig, port: str, *, fix: bool = False, margin_s: float = 0.002,
             cycles: int = 200, scan_bauds: Iterable[int] = STANDARD_BAUDS,
             sysfs_root: str | None = None) -> DoctorReport:
    """Run every check on ``port`` against ``cfg``; with ``fix`` repair what can be repaired.

    Later checks need the servos: when some are missing only the ones found are checked and
    the timed cycle is skipped (reported as a failure).
    """
    report = DoctorReport(port)
    check, done = check_latency(port, fix=fix, sysfs_root=sysfs_root)
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
