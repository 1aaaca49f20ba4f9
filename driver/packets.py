"""Dynamixel Protocol 2.0 codec: CRC-16, byte stuffing, instruction and status packets.

Pure code, no I/O; the driver and the emulator share it. Facts: ROBOTIS e-Manual,
"Protocol 2.0" (https://emanual.robotis.com/docs/en/dxl/protocol2/), summarised in
``docs/reference/protocol.md`` §1–2.

Frame: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM… | CRC_L CRC_H`` where LEN counts
INST + params (+ ERR for a status) + 2 CRC bytes *after* stuffing, and the CRC-16
(poly 0x8005, init 0, MSB-first) covers everything before it, also after stuffing.
"""
from __future__ import annotations

import array
import struct
import sys
from dataclasses import dataclass
from typing import Iterable, Iterator, Mapping, Sequence

from swerve.driver.errors import ChecksumError, CorruptPacketError
from swerve.driver.protocol import (ALERT_BIT, BACKUP_KEY, BROADCAST_ID, CLEAR_MULTI_TURN, HEADER, MAX_ID,
                                    MAX_LENGTH, PREFIX_BYTES, ErrorNumber, Instruction, ResetOption,
                                    StatusError, instruction_name)

# Protocol constants live in swerve.driver.protocol; they are re-exported here for codec users.
__all__ = ["ALERT_BIT", "BACKUP_KEY", "BROADCAST_ID", "CLEAR_MULTI_TURN", "HEADER", "MAX_ID", "MAX_LENGTH",
           "ErrorNumber", "Instruction", "ResetOption", "StatusError", "instruction_name"]

_STUFF_PATTERN = b"\xff\xff\xfd"
_STATUS = int(Instruction.STATUS)
_new = object.__new__


# --- CRC-16 (poly 0x8005, init 0x0000, MSB first, no reflection, no final XOR) -------------

def _make_crc_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def _make_crc_table16(t: tuple[int, ...]) -> list[int]:
    """Table for two bytes per step: ``crc' = table[crc ^ (b0 << 8 | b1)]``, i.e.
    ``table[h << 8 | lo] = ((t[h] << 8) & 0xFFFF) ^ t[lo ^ (t[h] >> 8)]``.

    That CRC is linear in its input (no init, no final XOR), so row ``h`` is ``t`` XOR-ed
    with ``table[h << 8]``; each row is made as one big-integer XOR of ``t`` packed as 256
    little-endian 16-bit fields (4x faster to import than the entry-by-entry comprehension).
    """
    packed = int.from_bytes(struct.pack("<256H", *t), "little")
    ones = int.from_bytes(b"\x01\x00" * 256, "little")       # 1 in every 16-bit field
    rows = array.array("H", b"".join(
        (packed ^ (((t[h] << 8) & 0xFFFF ^ t[t[h] >> 8]) * ones)).to_bytes(512, "little")
        for h in range(256)))
    if sys.byteorder == "big":
        rows.byteswap()
    return rows.tolist()


_CRC_TABLE16 = _make_crc_table16(_CRC_TABLE)
_WORDS: dict[int, struct.Struct] = {}     # big-endian 16-bit word unpackers by word count


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16 of ``data`` as Dynamixel Protocol 2.0 defines it; ``crc`` continues a running CRC.

    Works two bytes per step (a 65,536-entry table), with the last odd byte done alone.
    """
    n = len(data)
    half = n >> 1
    if half:
        fmt = _WORDS.get(half)
        if fmt is None:
            fmt = struct.Struct(f">{half}H")
            if half <= MAX_LENGTH:
                _WORDS[half] = fmt
        table = _CRC_TABLE16
        for w in fmt.unpack_from(data):
            crc = table[crc ^ w]
    if n & 1:
        crc = ((crc << 8) ^ _CRC_TABLE[(crc >> 8) ^ data[n - 1]]) & 0xFFFF
    return crc


# --- byte stuffing ---------------------------------------------------------------------------

def stuff(body: bytes) -> bytes:
    """Insert an ``FD`` after every ``FF FF FD`` in ``body`` (INST … last PARAM)."""
    if _STUFF_PATTERN not in body:
        return bytes(body)
    return bytes(body).replace(_STUFF_PATTERN, _STUFF_PATTERN + b"\xfd")


def unstuff(body: bytes) -> bytes:
    """Remove the ``FD`` inserted after every ``FF FF FD`` (inverse of :func:`stuff`)."""
    if _STUFF_PATTERN not in body:
        return bytes(body)
    return bytes(body).replace(_STUFF_PATTERN + b"\xfd", _STUFF_PATTERN)


#: Status frame heads by (ID, error byte, data length): the bytes before the data, their CRC.
_STATUS_HEADS: dict[tuple[int, int, int], tuple[bytes, int]] = {}
_STATUS_HEADS_MAX = 4096
_CRC_FIELD = struct.Struct("<H")


def status_frame(id_: int, error: int, params: bytes) -> bytes:
    """The wire frame of a status packet (stuffed, with CRC): :meth:`StatusPacket.encode`
    without building the packet, for an ID of 0..252 and an error byte the caller has checked.

    The head (header, ID, LENGTH, INST, ERR) and its running CRC depend only on the ID, the
    error byte and the data length, so a servo answering the same read again reuses them and
    only the data's CRC is computed. Data that needs stuffing (``FF FF FD``, or an error byte
    0xFF that could start the pattern) goes the general way.
    """
    if error == 0xFF or params.find(_STUFF_PATTERN) >= 0:
        return _frame(id_, bytes((_STATUS, error)) + params)
    key = (id_, error, len(params))
    head = _STATUS_HEADS.get(key)
    if head is None:
        if len(_STATUS_HEADS) >= _STATUS_HEADS_MAX:
            _STATUS_HEADS.clear()
        prefix = HEADER + bytes((id_,)) + _CRC_FIELD.pack(len(params) + 4) + bytes((_STATUS, error))
        head = _STATUS_HEADS[key] = (prefix, crc16(prefix))
    prefix, crc = head
    return prefix + params + _CRC_FIELD.pack(crc16(params, crc))


#: Instruction frame heads by (ID, instruction, parameter bytes): header, ID, LENGTH, INST; their CRC.
_INSTRUCTION_HEADS: dict[tuple[int, int, int], tuple[bytes, int]] = {}
_INSTRUCTION_HEADS_MAX = 4096


def instruction_frame(id_: int, instruction: int, params: bytes) -> bytes:
    """The wire frame of an instruction packet (stuffed, with CRC): :meth:`InstructionPacket.encode`
    for fields the packet has checked.

    The head (header, ID, LENGTH, INST) and its running CRC depend only on the ID, the instruction
    and the number of parameter bytes, so a request sent again (the control loop's Bulk Write)
    reuses them and only the parameters' CRC is computed. Parameters that need stuffing (``FF FF
    FD``, or an instruction byte 0xFF that could start the pattern) go the general way.
    """
    if instruction == 0xFF or params.find(_STUFF_PATTERN) >= 0:
        return _frame(id_, bytes((instruction,)) + params)
    key = (id_, instruction, len(params))
    head = _INSTRUCTION_HEADS.get(key)
    if head is None:
        if len(_INSTRUCTION_HEADS) >= _INSTRUCTION_HEADS_MAX:
            _INSTRUCTION_HEADS.clear()
        prefix = HEADER + _INSTRUCTION_HEAD.pack(id_, len(params) + 3, instruction)
        head = _INSTRUCTION_HEADS[key] = (prefix, crc16(prefix))
    prefix, crc = head
    return prefix + params + _CRC_FIELD.pack(crc16(params, crc))


#: ID, LENGTH and INST of an instruction frame's head.
_INSTRUCTION_HEAD = struct.Struct("<BHB")


def _frame(id_: int, body: bytes, *, stuffed: bool = True) -> bytes:
    """Wrap ``body`` (INST [ERR] params) into a full frame with header, LENGTH and CRC."""
    if stuffed:
        body = stuff(body)
    head = HEADER + bytes((id_,)) + struct.pack("<H", len(body) + 2)
    frame = head + body
    return frame + struct.pack("<H", crc16(frame))


def split_frame(frame: bytes) -> tuple[int, bytes]:
    """Check a complete frame's header, LENGTH and CRC; return ``(id, stuffed body)``.

    The body is INST [ERR] params, as received (still stuffed). Raises
    :class:`ChecksumError` or :class:`CorruptPacketError` naming what is wrong.
    """
    frame = bytes(frame)
    n = len(frame)
    if n < PREFIX_BYTES + 3:
        raise CorruptPacketError(f"frame too short ({n} bytes): {frame.hex(' ')}")
    if not frame.startswith(HEADER):
        raise CorruptPacketError(f"bad header {frame[:4].hex(' ')} (expected ff ff fd 00)")
    length = frame[5] | frame[6] << 8
    if length < 3 or PREFIX_BYTES + length != n:
        raise CorruptPacketError(f"LENGTH field {length} does not match a {n}-byte frame")
    body = frame[:-2]
    expected = crc16(body)
    if frame[-2] | frame[-1] << 8 != expected:
        raise ChecksumError(expected, frame[-2] | frame[-1] << 8, frame)
    return frame[4], body[PREFIX_BYTES:]


# --- packets -----------------------------------------------------------------------------------

def _check_id(id_: int, *, allow_broadcast: bool = True) -> None:
    if not (0 <= id_ <= MAX_ID or (allow_broadcast and id_ == BROADCAST_ID)):
        raise ValueError(f"invalid Dynamixel ID {id_} (0..252{', 254 broadcast' if allow_broadcast else ''})")


@dataclass(frozen=True)
class InstructionPacket:
    """An instruction from host to servo(s): ``id`` (0–252 or 0xFE), ``instruction``, raw ``params``."""

    id: int
    instruction: int
    params: bytes = b""

    def __post_init__(self) -> None:
        _check_id(self.id)
        if not 0 <= self.instruction <= 0xFF or self.instruction == Instruction.STATUS:
            raise ValueError(f"invalid instruction code {self.instruction!r}")
        object.__setattr__(self, "params", bytes(self.params))

    def encode(self) -> bytes:
        """The frame as sent on the wire (stuffed, with CRC)."""
        return instruction_frame(self.id, self.instruction, self.params)

    def wire_length(self) -> int:
        """``len(self.encode())`` without computing the CRC: header, ID and LENGTH
        (:data:`PREFIX_BYTES`), the stuffed INST and params, 2 CRC bytes."""
        body = bytes((self.instruction,)) + self.params
        return PREFIX_BYTES + len(body) + body.count(_STUFF_PATTERN) + 2     # one FD per pattern

    @classmethod
    def decode(cls, frame: bytes) -> "InstructionPacket":
        """Parse one complete instruction frame (raises on a bad CRC, length, header or ID)."""
        id_, body = split_frame(frame)
        if body[0] == _STATUS:
            raise CorruptPacketError("frame is a status packet, not an instruction")
        if not (0 <= id_ <= MAX_ID or id_ == BROADCAST_ID):
            raise CorruptPacketError(f"invalid ID {id_} in instruction frame")
        body = unstuff(body)
        pkt = _new(cls)                 # the fields are checked: an ID above, a non-status byte, bytes
        pkt.__dict__.update(id=id_, instruction=body[0], params=body[1:])
        return pkt

    @property
    def name(self) -> str:
        return instruction_name(self.instruction)


@dataclass(frozen=True)
class StatusPacket:
    """A status (reply) from one servo: ``id``, raw ``error`` byte, raw ``params``."""

    id: int
    error: int = 0
    params: bytes = b""

    def __post_init__(self) -> None:
        _check_id(self.id)
        if not 0 <= self.error <= 0xFF:
            raise ValueError(f"invalid error byte {self.error!r}")
        object.__setattr__(self, "params", bytes(self.params))

    @property
    def status_error(self) -> StatusError:
        return StatusError.from_byte(self.error)

    @property
    def error_number(self) -> ErrorNumber:
        return self.status_error.number

    @property
    def alert(self) -> bool:
        return bool(self.error & ALERT_BIT)

    def encode(self) -> bytes:
        """The frame as sent on the wire (stuffed, with CRC)."""
        return status_frame(self.id, self.error, self.params)

    @classmethod
    def decode(cls, frame: bytes) -> "StatusPacket":
        """Parse one complete (ordinary, stuffed) status frame."""
        id_, body = split_frame(frame)
        if body[0] != _STATUS or len(body) < 2:
            raise CorruptPacketError(f"not a status packet (instruction byte 0x{body[0]:02X}, "
                                     f"{len(body)} body bytes)")
        if id_ > MAX_ID:
            raise CorruptPacketError(f"invalid ID {id_} in status frame (a combined fast read "
                                     f"reply needs FastStatus.decode with the requested lengths)")
        if _STUFF_PATTERN in body:
            body = unstuff(body)
        return cls._checked(id_, body[1], body[2:])

    @classmethod
    def _checked(cls, id_: int, error: int, params: bytes) -> "StatusPacket":
        """A packet from fields a decoder has already checked (ID 0..252, a byte, bytes)."""
        pkt = _new(cls)
        pkt.__dict__.update(id=id_, error=error, params=params)
        return pkt


#: Bytes of a status frame before its data: header, ID, LENGTH, INST, ERR.
STATUS_HEAD_BYTES = PREFIX_BYTES + 2


@dataclass(frozen=True)
class ExpectedStatus:
    """An error-free status from servo ``id`` carrying ``length`` data bytes: a reply known in
    advance (a Sync Read's), checked by its head and the CRC of its data alone.

    ``head`` holds the frame's first :data:`STATUS_HEAD_BYTES` bytes (header, ID, LENGTH, INST,
    ERR 0) and ``head_crc`` their CRC-16, so :meth:`decode` compares the head, continues the CRC
    over the data and builds the :class:`StatusPacket`. It accepts exactly the frames
    :meth:`StatusPacket.decode` decodes to that ID, error 0 and ``length`` data bytes without
    unstuffing, and gives the same packet; anything else (an error byte, stuffed or corrupt
    data, a frame cut short) it leaves to :meth:`StatusPacket.decode`.
    """

    id: int
    length: int
    head: bytes
    head_crc: int

    @classmethod
    def of(cls, id_: int, length: int) -> "ExpectedStatus":
        """The expected status of servo ``id_`` (0..252) with ``length`` data bytes (0..MAX_LENGTH - 4)."""
        _check_id(id_, allow_broadcast=False)
        if not 0 <= length <= MAX_LENGTH - 4:
            raise ValueError(f"status data length {length} outside 0..{MAX_LENGTH - 4}")
        head = HEADER + struct.pack("<BHBB", id_, length + 4, _STATUS, 0)
        return cls(id_, length, head, crc16(head))

    @property
    def frame_bytes(self) -> int:
        """Bytes of the whole frame: head, data, CRC."""
        return STATUS_HEAD_BYTES + self.length + 2

    def decode(self, buf: bytes | bytearray) -> StatusPacket | None:
        """The status the frame at the start of ``buf`` holds if it is this one (head equal, no
        ``FF FF FD`` in the data, CRC right), else ``None``; ``buf`` may continue after it."""
        end = STATUS_HEAD_BYTES + self.length
        if (len(buf) < end + 2 or not buf.startswith(self.head)
                or buf.find(_STUFF_PATTERN, STATUS_HEAD_BYTES, end) >= 0):
            return None
        data = bytes(buf[STATUS_HEAD_BYTES:end])
        if crc16(data, self.head_crc) != buf[end] | buf[end + 1] << 8:
            return None
        return StatusPacket._checked(self.id, 0, data)


@dataclass(frozen=True)
class FastStatus:
    """The single combined reply to Fast Sync Read / Fast Bulk Read.

    ``entries`` holds one :class:`StatusPacket` per servo in the order they were listed.
    On the wire it is one frame with ID 0xFE and no byte stuffing::

        FF FF FD 00 FE LEN 55 | ERR1 ID1 DATA1 CRC1 | … | ERRn IDn DATAn CRCn

    where each CRCk is the running CRC-16 of the frame up to DATAk, so CRCn is the frame CRC.
    """

    entries: tuple[StatusPacket, ...]

    def encode(self) -> bytes:
        """Build the full combined frame."""
        length = fast_status_length([len(e.params) for e in self.entries])
        frame = bytearray(HEADER + bytes((BROADCAST_ID,)) + struct.pack("<H", length)
                          + bytes((Instruction.STATUS,)))
        if not self.entries:
            raise ValueError("a fast status needs at least one entry")
        for e in self.entries:
            frame += bytes((e.error, e.id)) + e.params
            frame += struct.pack("<H", crc16(frame))
        return bytes(frame)

    def slices(self) -> list[bytes]:
        """The frame cut into the slices each servo transmits in turn (first one sends the header)."""
        whole = self.encode()
        out, pos = [], 8
        for i, e in enumerate(self.entries):
            end = pos + FAST_ENTRY_OVERHEAD + len(e.params)
            out.append(whole[:end] if i == 0 else whole[pos:end])
            pos = end
        return out

    @classmethod
    def decode(cls, frame: bytes, lengths: Sequence[int]) -> "FastStatus":
        """Parse a combined frame given each entry's data length (as requested)."""
        frame = bytes(frame)
        expect = fast_status_length(lengths)
        if len(frame) != PREFIX_BYTES + expect:
            raise CorruptPacketError(
                f"fast read reply is {len(frame)} bytes, expected {fast_status_bytes(lengths)} "
                f"for lengths {list(lengths)}")
        if not frame.startswith(HEADER) or (frame[5] | frame[6] << 8) != expect:
            raise CorruptPacketError(f"bad header or LENGTH in fast read reply {frame[:7].hex(' ')}")
        if frame[4] != BROADCAST_ID or frame[PREFIX_BYTES] != _STATUS:
            raise CorruptPacketError("not a fast sync/bulk read reply (ID must be 0xFE, instruction 0x55)")
        # the running CRC after the last entry is the frame's CRC: one pass checks both
        entries = []
        for pos, end, crc in fast_entries(frame, lengths):
            crc_k = frame[end] | frame[end + 1] << 8
            if crc_k != crc:
                raise ChecksumError(crc, crc_k, frame)
            sid = frame[pos + 1]
            if sid > MAX_ID:
                raise CorruptPacketError(f"invalid ID {sid} inside fast read reply")
            entries.append(StatusPacket._checked(sid, frame[pos], frame[pos + 2:end]))
        return cls(tuple(entries))


#: Bytes of one entry of a combined fast read reply besides its data: ERR, ID, CRC (2).
FAST_ENTRY_OVERHEAD = 4


def fast_status_length(lengths: Sequence[int]) -> int:
    """LENGTH field of a combined fast read reply with data ``lengths`` (INST + per entry
    ERR, ID, data, CRC)."""
    return 1 + sum(lengths) + FAST_ENTRY_OVERHEAD * len(lengths)


def fast_status_bytes(lengths: Sequence[int]) -> int:
    """Bytes on the wire of a combined fast read reply with data ``lengths`` (header, ID,
    LENGTH and the :func:`fast_status_length` bytes it counts)."""
    return PREFIX_BYTES + fast_status_length(lengths)


def fast_entries(buf: bytes | bytearray, lengths: Sequence[int]) -> Iterator[tuple[int, int, int]]:
    """Walk the entries of a combined fast read reply at the start of ``buf``.

    Yields ``(pos, end, crc)`` for each entry whose bytes are all in ``buf``, in order:
    ``buf[pos]`` is its ERR byte, ``buf[pos + 1]`` its ID, ``buf[pos + 2:end]`` its data and
    ``buf[end:end + 2]`` its CRC field, which must hold ``crc``, the running CRC-16 of the frame
    up to the end of that data. Stops at the first entry cut short; checks nothing itself.
    """
    pos = PREFIX_BYTES + 1
    crc = crc16(buf[:pos])
    for n in lengths:
        end = pos + 2 + n
        if end + 2 > len(buf):
            return
        crc = crc16(buf[pos:end], crc)
        yield pos, end, crc
        crc = crc16(buf[end:end + 2], crc)
        pos = end + 2


Packet = InstructionPacket | StatusPacket


def decode_frame(frame: bytes, fast_lengths: Sequence[int] | None = None) -> Packet | FastStatus:
    """Decode one complete frame with the ``decode`` of its kind.

    A status with ID 0xFE is a combined fast read reply: :meth:`FastStatus.decode` with
    the requested ``fast_lengths`` (CorruptPacketError when none were requested). Any other
    status goes to :meth:`StatusPacket.decode`, everything else to
    :meth:`InstructionPacket.decode`.
    """
    if len(frame) > PREFIX_BYTES and frame[PREFIX_BYTES] == _STATUS:
        if frame[4] == BROADCAST_ID:
            if fast_lengths is None:
                raise CorruptPacketError("combined fast read reply arrived, but none was requested")
            return FastStatus.decode(frame, fast_lengths)
        return StatusPacket.decode(frame)
    return InstructionPacket.decode(frame)


# --- builders for every instruction -----------------------------------------------------------

def _u16(v: int) -> bytes:
    return struct.pack("<H", v)


#: ID, address and data length of one bulk read/write entry.
_ID_ADDRESS_LENGTH = struct.Struct("<BHH")


def ping(id_: int) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.PING)


def read(id_: int, address: int, length: int) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.READ, _u16(address) + _u16(length))


def write(id_: int, address: int, data: bytes) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.WRITE, _u16(address) + bytes(data))


def reg_write(id_: int, address: int, data: bytes) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.REG_WRITE, _u16(address) + bytes(data))


def action(id_: int) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.ACTION)


def factory_reset(id_: int, option: int = ResetOption.EXCEPT_ID_BAUD) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.FACTORY_RESET, bytes((int(ResetOption(option)),)))


def reboot(id_: int) -> InstructionPacket:
    return InstructionPacket(id_, Instruction.REBOOT)


def clear(id_: int) -> InstructionPacket:
    """Clear (multi-turn position) — option 0x01 followed by the fixed key ``44 58 4C 22``."""
    return InstructionPacket(id_, Instruction.CLEAR, CLEAR_MULTI_TURN)


def control_table_backup(id_: int, restore: bool = False) -> InstructionPacket:
    """Control Table Backup: store (0x01) or restore (0x02), then the fixed key ``CTRL``."""
    return InstructionPacket(id_, Instruction.CONTROL_TABLE_BACKUP,
                             bytes((0x02 if restore else 0x01,)) + BACKUP_KEY)


def sync_read(address: int, length: int, ids: Iterable[int], fast: bool = False) -> InstructionPacket:
    ids = bytes(ids)
    for i in ids:
        _check_id(i, allow_broadcast=False)
    inst = Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ
    return InstructionPacket(BROADCAST_ID, inst, _u16(address) + _u16(length) + ids)


def sync_write(address: int, length: int, data: Mapping[int, bytes]) -> InstructionPacket:
    params = bytearray(_u16(address) + _u16(length))
    for id_, d in data.items():
        _check_id(id_, allow_broadcast=False)
        if len(d) != length:
            raise ValueError(f"sync write data for ID {id_} is {len(d)} bytes, expected {length}")
        params += bytes((id_,)) + bytes(d)
    return InstructionPacket(BROADCAST_ID, Instruction.SYNC_WRITE, params)


def _bulk_entries(items: Iterable[tuple], what: str) -> Iterator[tuple]:
    """``items`` of a bulk instruction, each checked: an ID of 0..252, listed once."""
    seen = set()
    for item in items:
        id_ = item[0]
        _check_id(id_, allow_broadcast=False)
        if id_ in seen:
            raise ValueError(f"ID {id_} appears twice in a {what}")
        seen.add(id_)
        yield item


def bulk_read(items: Iterable[tuple[int, int, int]], fast: bool = False) -> InstructionPacket:
    """``items``: ``(id, address, length)`` per servo; an ID may appear only once."""
    params = bytearray()
    for id_, address, length in _bulk_entries(items, "bulk read"):
        params += _ID_ADDRESS_LENGTH.pack(id_, address, length)
    inst = Instruction.FAST_BULK_READ if fast else Instruction.BULK_READ
    return InstructionPacket(BROADCAST_ID, inst, params)


def bulk_write(items: Iterable[tuple[int, int, bytes]]) -> InstructionPacket:
    """``items``: ``(id, address, data)`` per servo; an ID may appear only once."""
    params = bytearray()
    for id_, address, data in _bulk_entries(items, "bulk write"):
        data = bytes(data)
        params += _ID_ADDRESS_LENGTH.pack(id_, address, len(data)) + data
    return InstructionPacket(BROADCAST_ID, Instruction.BULK_WRITE, params)


# --- parameter parsers (the servo side) -------------------------------------------------------

def parse_address_length(params: bytes) -> tuple[int, int]:
    """``(address, length)`` of a Read / Sync Read head; raises on short params."""
    if len(params) < 4:
        raise CorruptPacketError(f"expected address and length (4 bytes), got {len(params)}")
    return struct.unpack_from("<HH", params)


def parse_sync_read(params: bytes) -> tuple[int, int, tuple[int, ...]]:
    address, length = parse_address_length(params)
    return address, length, tuple(params[4:])


def parse_sync_write(params: bytes) -> tuple[int, int, dict[int, bytes]]:
    address, length = parse_address_length(params)
    rest, out = params[4:], {}
    step = 1 + length
    if length == 0 or len(rest) % step:
        raise CorruptPacketError(f"sync write block of {len(rest)} bytes is not a multiple of 1+{length}")
    for i in range(0, len(rest), step):
        out[rest[i]] = rest[i + 1:i + step]
    return address, length, out


def parse_bulk_read(params: bytes) -> list[tuple[int, int, int]]:
    if len(params) % 5:
        raise CorruptPacketError(f"bulk read params of {len(params)} bytes are not a multiple of 5")
    return [(params[i],) + struct.unpack_from("<HH", params, i + 1) for i in range(0, len(params), 5)]


def parse_bulk_write(params: bytes) -> list[tuple[int, int, bytes]]:
    params = bytes(params)              # its slices are then bytes (no copy if it is bytes)
    out, pos, n = [], 0, len(params)
    head = _ID_ADDRESS_LENGTH.unpack_from
    while pos < n:
        if pos + 5 > n:
            raise CorruptPacketError("truncated bulk write entry")
        id_, address, length = head(params, pos)
        end = pos + 5 + length
        if end > n:
            raise CorruptPacketError(f"bulk write entry for ID {id_} is truncated")
        out.append((id_, address, params[pos + 5:end]))
        pos = end
    return out
