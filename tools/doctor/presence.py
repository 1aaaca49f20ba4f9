"""Are the robot file's servos on the bus at its baud? If not, where are they, and which
stray servo should become which missing ID (``--fix`` moves it: ID, then Baud Rate, EEPROM items
written with the torque off; the new ID/baud takes effect after the status reply)."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Iterable

from swerve.driver.bus import Bus, PingResult
from swerve.driver.control_table import SCAN_BAUDS_BPS, Reg, baud_index
from swerve.driver.errors import CorruptPacketError, DxlError, DxlTimeoutError
from swerve.driver.robot_config import RobotConfig
from swerve.tools.doctor.report import FAIL, PASS, Check, DoctorReport, ids_text


@dataclass
class Location:
    """Where a servo answered: ``baud`` bps and its Ping result."""

    baud: int
    ping: PingResult


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


def locate_all(port: str, bauds: Iterable[int] = SCAN_BAUDS_BPS, ids: Iterable[int] = range(0, 253),
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
                   report: DoctorReport, scan_bauds: Iterable[int] = SCAN_BAUDS_BPS) -> dict[int, PingResult]:
    """Every ID of the robot file at the file's baud; else scan and say where each servo is."""
    want = list(cfg.drive_ids + cfg.steer_ids)
    baud = cfg.link.baud
    found = ping_ids(port, baud, want, margin_s)
    missing = [i for i in want if i not in found]
    if not missing:
        report.checks.append(Check("servos present", PASS,
                                   f"IDs {ids_text(want)} answer at {baud} bps"))
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
                                       f"IDs {ids_text(want)} answer at {baud} bps (after moving "
                                       f"{len(moves)} servo(s))"))
            return found
    plan = ", ".join(f"ID {s.ping.id} at {s.baud} bps -> ID {t} at {baud} bps"
                     for t, s in sorted(moves.items()))
    fix_text = (f"swerve doctor --fix moves {plan}" if moves else
                "connect the missing servos one at a time and run swerve doctor --fix; check power and "
                "cables")
    report.checks.append(Check(
        "servos present", FAIL,
        f"IDs {ids_text(missing)} do not answer at {baud} bps; other servos found: {where}", fix_text))
    return found
