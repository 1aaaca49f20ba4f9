"""What every Protocol 2.0 instruction does on the emulated bus, in one place.

:func:`dispatch` takes one decoded :class:`~swerve.driver.packets.InstructionPacket` and the
servos that hear it, and returns the replies to send (in order, each with its delay) and the
servos it touched. Unicast and broadcast instructions (Ping, Read, Write, Reg Write, Action,
Reboot, Factory Reset, Clear, Control Table Backup) run through :func:`execute` on each
addressed servo and then the reply rules of :func:`answer` (broadcast, Secondary ID, Status
Return Level); Sync/Bulk Write and (Fast) Sync/Bulk Read run across the listed servos here.
The servo (:class:`~swerve.emulator.servo.VirtualServo`) holds the state these act on; no
function here does I/O or timing (the server writes the replies, :mod:`.reply_pacing` paces them).

Reply order: broadcast Ping in ascending ID order; Sync/Bulk Read in listed order; Fast
Sync/Bulk Read as one combined frame (:class:`driver.packets.FastStatus`), one slice per servo.
Semantics from the e-Manual, Protocol 2.0 (https://emanual.robotis.com/docs/en/dxl/protocol2/).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

from swerve.driver.errors import CorruptPacketError
from swerve.driver.packets import (BACKUP_KEY, BROADCAST_ID, CLEAR_MULTI_TURN, MAX_ID, MAX_LENGTH, ErrorNumber,
                                   FastStatus, Instruction, InstructionPacket, StatusPacket, fast_status_length,
                                   parse_address_length, parse_bulk_read, parse_bulk_write, parse_sync_read,
                                   parse_sync_write)
from swerve.emulator.memory import RESET_ALL, RESET_EXCEPT_ID, RESET_EXCEPT_ID_BAUD
from swerve.emulator.servo import VirtualServo

log = logging.getLogger(__name__)

SYNC_READS = (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
BULK_READS = (Instruction.BULK_READ, Instruction.FAST_BULK_READ)
FAST_READS = (Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ)
BUS_WRITES = (Instruction.SYNC_WRITE, Instruction.BULK_WRITE)
BUS_INSTRUCTIONS = SYNC_READS + BULK_READS + BUS_WRITES
#: Instructions that change no ID or baud item, so the touched servos need no :meth:`VirtualServo.apply_pending`.
READS_ONLY = SYNC_READS + BULK_READS


@dataclass(slots=True)
class Reply:
    """One status frame to send."""

    frame: bytes
    delay_s: float         # wait after the previous reply (or the instruction) ends
    fast: bool = False     # part of a combined fast-read frame (one fault draw per frame)


@dataclass(frozen=True)
class DispatchRules:
    """The bus-wide choices of :func:`dispatch` (from :class:`~swerve.emulator.server.LinkSettings`).

    ``sync_chain_break``: in a Sync/Bulk Read, servos listed after an absent one stay silent too.
    ``broadcast_slot_s``: spacing of the replies to a broadcast Ping, s.
    """

    sync_chain_break: bool = True
    broadcast_slot_s: float = 1e-4


def addressed(listening: Sequence[VirtualServo], id_: int) -> list[tuple[VirtualServo, bool]]:
    """``(servo, by_primary_id)`` for every listening servo the packet ID ``id_`` addresses."""
    out = []
    for s in listening:
        if id_ == BROADCAST_ID or s.id == id_:
            out.append((s, True))
        elif s.secondary_id <= MAX_ID and s.secondary_id == id_:
            out.append((s, False))
    return out


def crc_error_replies(listening: Sequence[VirtualServo], id_: int) -> list[Reply]:
    """The CRC Error (0x03) statuses of the servos a unicast frame with a bad CRC addressed
    (by primary ID, Status Return Level 2)."""
    return [Reply(s.status(ErrorNumber.CRC).encode(), s.return_delay_s)
            for s, primary in addressed(listening, id_) if primary and s.status_return_level == 2]


def dispatch(pkt: InstructionPacket, listening: Sequence[VirtualServo],
             rules: DispatchRules) -> tuple[list[Reply], list[VirtualServo]]:
    """``(replies, touched)`` of instruction ``pkt`` on the ``listening`` servos (ascending IDs).

    Raises :class:`~swerve.driver.errors.CorruptPacketError` for parameters that make no sense
    (e.g. a Sync Write block of the wrong size); nothing has been executed then.
    """
    inst = pkt.instruction
    if inst in BUS_INSTRUCTIONS and pkt.id == BROADCAST_ID:
        if inst in BUS_WRITES:
            return [], _bus_write(pkt, listening)
        return _bus_read(pkt, listening, rules)
    replies: list[Reply] = []
    touched = []
    broadcast_ping = pkt.id == BROADCAST_ID and inst == Instruction.PING
    for servo, _primary in addressed(listening, pkt.id):
        status = answer(servo, pkt, execute(servo, pkt))
        touched.append(servo)
        if status is not None:
            delay = servo.return_delay_s + (rules.broadcast_slot_s if broadcast_ping and replies else 0.0)
            replies.append(Reply(status.encode(), delay))
    return replies, touched


def execute(servo: VirtualServo, pkt: InstructionPacket) -> StatusPacket | None:
    """Execute ``pkt`` (addressed to ``servo``, its Secondary ID or broadcast) on ``servo``.

    Returns the status to send before the reply rules of :func:`answer` (``None``: the
    protocol sends nothing). Sync/Bulk instructions go through :func:`dispatch`.
    """
    servo.note_traffic()
    reply_id = servo.id
    inst = pkt.instruction
    p = pkt.params
    if inst == Instruction.PING:
        return servo.status(params=servo.model_number.to_bytes(2, "little") + bytes((servo.firmware_version,)))
    if inst == Instruction.READ:
        if len(p) != 4:
            return servo.status(ErrorNumber.DATA_LENGTH)
        return servo.read_status(*parse_address_length(p))
    if inst in (Instruction.WRITE, Instruction.REG_WRITE):
        if len(p) < 3:
            return servo.status(ErrorNumber.DATA_LENGTH)
        address, data = int.from_bytes(p[:2], "little"), p[2:]
        if inst == Instruction.WRITE:
            return servo.status(servo.bus_write(address, data), reply_id=reply_id)
        return servo.status(servo.register_write(address, data))
    if inst == Instruction.ACTION:
        return servo.status(servo.action())
    if inst == Instruction.REBOOT:
        status = servo.status()
        servo.reboot()
        return status
    if inst == Instruction.FACTORY_RESET:
        return _factory_reset(servo, pkt)
    if inst == Instruction.CLEAR:
        if len(p) != len(CLEAR_MULTI_TURN):
            return servo.status(ErrorNumber.DATA_LENGTH)
        if bytes(p) != CLEAR_MULTI_TURN:
            return servo.status(ErrorNumber.DATA_RANGE)
        return servo.status(servo.clear_multi_turn())
    if inst == Instruction.CONTROL_TABLE_BACKUP:
        return _control_table_backup(servo, p)
    return servo.status(ErrorNumber.INSTRUCTION)


def answer(servo: VirtualServo, pkt: InstructionPacket, status: StatusPacket | None) -> StatusPacket | None:
    """The reply ``servo`` sends to ``pkt`` given the ``status`` :func:`execute` produced:
    broadcast, Secondary ID and Status Return Level rules applied."""
    if status is None or pkt.id == BROADCAST_ID:
        return status if (status is not None and pkt.instruction == Instruction.PING) else None
    if pkt.id != status.id and pkt.id == servo.secondary_id:
        return None          # addressed through the Secondary ID: executed, never answered
    level = servo.status_return_level
    if pkt.instruction == Instruction.PING:
        return status
    if level == 0 or (level == 1 and pkt.instruction != Instruction.READ):
        return None
    return status


def _factory_reset(servo: VirtualServo, pkt: InstructionPacket) -> StatusPacket | None:
    if len(pkt.params) != 1:
        return servo.status(ErrorNumber.DATA_LENGTH)
    option = pkt.params[0]
    if option not in (RESET_ALL, RESET_EXCEPT_ID, RESET_EXCEPT_ID_BAUD):
        return servo.status(ErrorNumber.DATA_RANGE)
    if pkt.id == BROADCAST_ID and option == RESET_ALL:
        return None      # firmware >= 42 ignores a broadcast reset-all (would clash IDs)
    status = servo.status()
    servo.factory_reset(option)
    return status


def _control_table_backup(servo: VirtualServo, p: bytes) -> StatusPacket:
    if len(p) != 5:
        return servo.status(ErrorNumber.DATA_LENGTH)
    if bytes(p[1:]) != BACKUP_KEY or p[0] not in (1, 2):
        return servo.status(ErrorNumber.DATA_RANGE)
    if servo.torque_enabled:
        return servo.status(ErrorNumber.RESULT_FAIL)
    if p[0] == 1:
        servo.store_backup()
        return servo.status()
    if not servo.has_backup:
        return servo.status(ErrorNumber.RESULT_FAIL)
    status = servo.status()
    servo.restore_backup()
    return status


def _writers(listening: Sequence[VirtualServo]) -> dict[int, list[VirtualServo]]:
    """The servos an ID in a Sync/Bulk Write addresses (its ID or Secondary ID), by ID."""
    out: dict[int, list[VirtualServo]] = {}
    for s in listening:
        out.setdefault(s.id, []).append(s)
        if s.secondary_id <= MAX_ID and s.secondary_id != s.id:
            out.setdefault(s.secondary_id, []).append(s)
    return out


def _bus_write(pkt: InstructionPacket, listening: Sequence[VirtualServo]) -> list[VirtualServo]:
    """A Sync or Bulk Write: every listed entry written (no reply); the servos touched."""
    if pkt.instruction == Instruction.SYNC_WRITE:
        address, _length, data = parse_sync_write(pkt.params)
        entries = [(id_, address, d) for id_, d in data.items()]
    else:
        entries = parse_bulk_write(pkt.params)
    writers = _writers(listening)
    touched = []
    for id_, address, d in entries:
        for s in writers.get(id_, ()):
            s.note_traffic()
            s.bus_write(address, d)
            touched.append(s)
    return touched


def _bus_read(pkt: InstructionPacket, listening: Sequence[VirtualServo],
              rules: DispatchRules) -> tuple[list[Reply], list[VirtualServo]]:
    """A (Fast) Sync or Bulk Read: the replies in listed order and the servos read."""
    by_id = {s.id: s for s in listening}
    if pkt.instruction in SYNC_READS:
        address, length, ids = parse_sync_read(pkt.params)
        if pkt.instruction == Instruction.SYNC_READ and _plain_everywhere(listening, address, length):
            return plain_sync_read(address, length, ids, by_id, rules)
        items = [(i, address, length) for i in ids]
    else:
        items = parse_bulk_read(pkt.params)
        if len({i for i, _, _ in items}) != len(items):
            log.debug("bulk read lists an ID twice; ignored")
            return [], []
    if pkt.instruction in FAST_READS:
        return _fast_read(items, by_id, rules)
    return listed_reads(items, by_id, rules)


def _plain_everywhere(listening: Sequence[VirtualServo], address: int, length: int) -> bool:
    """True if a read of ``length`` bytes at ``address`` is a plain copy of the stored bytes
    (:meth:`~swerve.emulator.memory.ServoMemory.plain_range`) on every listening servo (they
    share one control table, so the first one's answer holds for all)."""
    if not listening:
        return False
    table = listening[0].table
    return listening[0].memory.plain_range(address, length) and all(s.table is table for s in listening)


def listed_reads(items: Sequence[tuple[int, int, int]], by_id: dict[int, VirtualServo],
                 rules: DispatchRules) -> tuple[list[Reply], list[VirtualServo]]:
    """Replies and servos read of a Sync or Bulk Read of ``items`` ``(id, address, length)``
    (any IDs and ranges; ``by_id``: the listening servos): every listed servo reads (and
    publishes its present items) before any reply is built; replies in listed order."""
    frames: list[tuple[VirtualServo | None, bytes]] = []
    for id_, address, length in items:
        s = by_id.get(id_)
        if s is None:
            frames.append((None, b""))
            continue
        s.note_traffic()
        frames.append((s, s.read_frame(address, length)))
    present = [s for s, _ in frames if s is not None]
    if not present:
        return [], []
    replies = []
    for s, frame in frames:
        if s is None:
            if rules.sync_chain_break:
                break
            continue
        replies.append(Reply(frame, s.return_delay_s))
    return replies, present


def plain_sync_read(address: int, length: int, ids: Sequence[int], by_id: dict[int, VirtualServo],
                    rules: DispatchRules) -> tuple[list[Reply], list[VirtualServo]]:
    """:func:`listed_reads` of a Sync Read of ``length`` bytes at ``address`` from ``ids``, for
    a range that is plain on every servo (``_plain_everywhere``): one call per servo
    (:meth:`VirtualServo.plain_read_reply`). The same replies and servo states."""
    end = address + length
    replies: list[Reply] = []
    present: list[VirtualServo] = []
    silent = False                      # a listed servo was absent: later replies are dropped
    for id_ in ids:
        s = by_id.get(id_)
        if s is None:
            silent = silent or rules.sync_chain_break
            continue
        present.append(s)
        frame, delay_s = s.plain_read_reply(address, end)
        if not silent:
            replies.append(Reply(frame, delay_s))
    return replies, present


def _fast_read(items: list[tuple[int, int, int]], by_id: dict[int, VirtualServo],
               rules: DispatchRules) -> tuple[list[Reply], list[VirtualServo]]:
    """Replies and servos read of a Fast Sync/Bulk Read of ``items`` ``(id, address, length)``:
    one combined frame, cut into each answering servo's slice."""
    if fast_status_length([n for _, _, n in items]) > MAX_LENGTH:
        raise CorruptPacketError("fast read reply would exceed the largest frame")
    statuses: list[tuple[VirtualServo | None, StatusPacket]] = []
    for id_, address, length in items:
        s = by_id.get(id_)
        if s is None:
            statuses.append((None, StatusPacket(id_ if id_ <= MAX_ID else 0, 0, bytes(length))))
            continue
        s.note_traffic()
        st = s.read_status(address, length)
        if len(st.params) != length:       # keep the combined frame's layout
            st = StatusPacket(st.id, st.error, bytes(length))
        statuses.append((s, st))
    present = [s for s, _ in statuses if s is not None]
    if not present:
        return [], []
    slices = FastStatus(tuple(st for _, st in statuses)).slices()
    replies = []
    for k, ((s, _), frame) in enumerate(zip(statuses, slices)):
        if s is None:
            if rules.sync_chain_break:
                break
            continue
        replies.append(Reply(frame, s.return_delay_s if k == 0 else 0.0, fast=True))
    return replies, present
