"""Reading a run log's MCAP file record by record, without its index: :func:`scan`.

A log that was never closed (a crash, SIGKILL) has no summary or footer, and a damaged one has
unreadable stretches; :func:`scan` walks the top-level records by their length fields, parses the
ones a run log needs (Schema, Channel, Message, and the records inside each Chunk, decompressed
and CRC-checked by the ``mcap`` package) into the ``mcap`` package's record classes, stops at a
record cut off by the end of the file, and notes any other unreadable record as :class:`Damage`,
resuming at the next well-formed chunk. Messages are cut out of a chunk with ``struct`` (their
fields are fixed), the other records are read by ``mcap``.
"""
from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import get_chunk_data_stream

from swerve.driver.errors import ConfigError

#: MCAP opcodes (the spec's record types 0x01-0x10); anything else at a record start is damage.
_OPCODES = range(0x01, 0x11)
_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class Damage:
    """A stretch of a log that could not be read: it starts at byte ``offset`` of the ``.mcap``
    file and reading went on at byte ``resumed`` (``None``: nothing readable followed)."""

    offset: int
    reason: str
    resumed: int | None

    def __str__(self) -> str:
        tail = "nothing readable after it" if self.resumed is None else f"reading resumed at byte {self.resumed}"
        return f"damaged at byte {self.offset} ({self.reason}; {tail})"


#: MCAP records whose contents :func:`_record_at` reads (Schema, Channel, Message, Chunk).
_READ_OPCODES = frozenset((0x03, 0x04, 0x05, 0x06))
_RECORD_HEAD = struct.Struct("<BQ")
#: Message record fields before its data: channel ID, sequence, log time, publish time.
_MESSAGE_FIELDS = struct.Struct("<HIQQ")


def _record_at(data: bytes, pos: int):
    """``(records, end)`` of the top-level MCAP record at ``pos``: a chunk yields its inner records.

    Raises ``EOFError`` if the record runs past the end of the file, ``ValueError`` (with the
    reason) if it is not a well-formed record.
    """
    if pos + 9 > len(data):
        raise EOFError("record header cut short")
    opcode, length = _RECORD_HEAD.unpack_from(data, pos)
    if opcode not in _OPCODES:
        raise ValueError(f"no MCAP record starts there (opcode 0x{opcode:02x})")
    end = pos + 9 + length
    if end > len(data):
        raise EOFError(f"a record of {length} bytes runs past the end of the file")
    if opcode == 0x02:
        return ["footer"], end
    if opcode not in _READ_OPCODES:
        return [], end                   # header, indexes, statistics...: not needed here
    try:
        if opcode != 0x06:
            return [_inner_record(opcode, data[pos + 9:end], whole=True)], end
        stream = ReadDataStream(io.BytesIO(data[pos + 9:end]))
        chunk = Chunk.read(stream)
        if stream.count != length:
            raise ValueError("its fields do not fill its length")
        inner, size = get_chunk_data_stream(chunk, validate_crc=True)   # decompressed, CRC checked
        records, read = [], inner.read
        while inner.count < size:
            op, n = _RECORD_HEAD.unpack(read(9))
            if op in _READ_OPCODES:
                records.append(_inner_record(op, read(n)))
            else:
                read(n)
        return records, end
    except (McapError, EOFError, struct.error, ValueError, UnicodeDecodeError, KeyError) as exc:
        raise ValueError(f"malformed record (opcode 0x{opcode:02x}: {type(exc).__name__})") from None


def _inner_record(opcode: int, body: bytes, whole: bool = False):
    """The ``mcap`` record (Schema, Channel or Message) of one record's contents ``body``;
    ``whole``: its fields must fill ``body`` (a top-level record)."""
    if opcode == 0x05:
        if len(body) < _MESSAGE_FIELDS.size:
            raise ValueError("a message record shorter than its fields")
        channel_id, sequence, log_time, publish_time = _MESSAGE_FIELDS.unpack_from(body)
        return Message(channel_id=channel_id, log_time=log_time, data=body[_MESSAGE_FIELDS.size:],
                       publish_time=publish_time, sequence=sequence)
    if opcode == 0x06:
        raise ValueError("a chunk inside a chunk")
    stream = ReadDataStream(io.BytesIO(body))
    rec = (Schema if opcode == 0x03 else Channel).read(stream)
    if whole and stream.count != len(body):
        raise ValueError("its fields do not fill its length")
    return rec


def _resync(data: bytes, pos: int) -> int | None:
    """Start of the first well-formed chunk after ``pos``, or ``None``."""
    cand = data.find(b"\x06", pos + 1)
    while cand != -1:
        try:
            _record_at(data, cand)
            return cand
        except (EOFError, ValueError):
            cand = data.find(b"\x06", cand + 1)
    return None


def scan(mcap_path: Path):
    """Walk every top-level record; return ``(channels, schemas, messages, footer_seen, damage)``.

    A record cut off by the end of the file is the unwritten tail of a log that was never
    closed (a crash): reading stops there without damage. Any other unreadable record is
    damage: its byte offset is noted and reading resumes at the next well-formed chunk.
    """
    try:
        data = mcap_path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read run log {mcap_path}: {exc.strerror}") from None
    if not data.startswith(_MAGIC):
        raise ConfigError(f"not a swerve run log: {mcap_path} is not an MCAP file (no MCAP magic)")
    channels, schemas, messages, footer, damage = {}, {}, [], False, []
    pos = len(_MAGIC)
    while pos < len(data) and not footer:
        try:
            recs, pos_next = _record_at(data, pos)
        except (EOFError, ValueError) as exc:
            nxt = _resync(data, pos)
            if isinstance(exc, EOFError) and nxt is None:
                break                            # the cut tail of an unclosed log
            damage.append(Damage(pos, str(exc), nxt))
            if nxt is None:
                break
            pos = nxt
            continue
        for rec in recs:
            if isinstance(rec, Message):
                messages.append((pos, rec))
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif rec == "footer":
                footer = True
        pos = pos_next
    if not channels:
        where = f" ({damage[0]})" if damage else ""
        raise ConfigError(f"not a swerve run log: {mcap_path} holds no readable channel{where}")
    return channels, schemas, messages, footer, damage
