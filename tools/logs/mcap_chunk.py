"""The run log's MCAP chunks, packed with ``struct``: what rosbags' ``McapWriter`` writes for the same
messages, byte for byte, at a fraction of its per-message cost.

rosbags builds every record field by field (a ``BytesIO`` and an ``int.to_bytes`` per field), which
made the chunk a cycle closes (crash safety) the largest part of the log's cost. :class:`ChunkWriter`
keeps the pending messages as ``(channel, time, CDR bytes)`` and, on :meth:`~ChunkWriter.flush`,
packs the chunk in a few ``struct`` calls and one file write. The records are those of the MCAP
specification (https://mcap.dev/spec, "Records": Message 0x05, Chunk 0x06, Message Index 0x07,
Chunk Index 0x08), with the choices rosbags 0.11 makes in ``McapWriter.write`` and
``close_chunk``: sequence 0, publish time = log time, no compression, uncompressed CRC 0, one Message
Index record per channel in the order of the channel's first message in the chunk, and a chunk
closed once its records pass 1 MiB.

The bag's summary (written by rosbags on close) needs the chunk indexes and the message counts:
:meth:`~ChunkWriter.flush` hands them to the bag's ``McapWriter`` and ``Writer``, as their own
``write`` and ``close_chunk`` would have. ``tests/tools/logs/test_mcap_chunk.py`` checks the file
against one written message by message with rosbags.
"""
from __future__ import annotations

import struct
from io import BytesIO

#: MCAP opcodes (MCAP specification, "Records").
OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = 0x05, 0x06, 0x07
#: rosbags' ``McapWriter.write`` closes the pending chunk once its records exceed this many bytes.
CHUNK_LIMIT = 2**20

#: Message record up to its data: opcode, record length, channel ID, sequence, log time, publish time.
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS = _MESSAGE_HEAD.size - 9          # the record's length without its data
#: Chunk record up to its records: opcode, record length, start time, end time, uncompressed size,
#: uncompressed CRC (0: not computed), compression (the empty string: its length 0), records' size.
_CHUNK_HEAD = struct.Struct("<BQQQQIIQ")
_CHUNK_FIELDS = _CHUNK_HEAD.size - 9
#: Message Index record head: opcode, record length, channel ID, length of the (time, offset) array.
_INDEX_HEAD = "<BQHI"
#: Chunk Index record, head and tail around its (channel ID, offset) map (kept in memory for the
#: summary; rosbags writes it with its own opcode and length on close).
_CHUNK_INDEX_HEAD = struct.Struct("<QQQQI")
_CHUNK_INDEX_TAIL = struct.Struct("<QIQQ")
_CHANNEL_OFFSET = struct.Struct("<HQ")


class ChunkWriter:
    """Pending messages of an open rosbags MCAP bag, written as chunks by :meth:`flush`.

    Parameters
    ----------
    bag : rosbags.rosbag2.Writer
        Opened with MCAP storage and no compression, its connections added and its own pending
        chunk empty (closed): from then on every message goes through this writer.

    Raises
    ------
    RuntimeError
        If the bag's storage is not the rosbags 0.11 ``McapWriter`` this was made for.
    """

    def __init__(self, bag):
        storage = bag.storage
        needed = ("bio", "chunk", "chunks", "channel_stats", "message_start_time", "message_end_time",
                  "compression")
        if (not all(hasattr(storage, n) for n in needed) or storage.compression != ""
                or not all(hasattr(bag, n) for n in ("counts", "min_timestamp", "max_timestamp"))):
            raise RuntimeError("the bag's storage is not rosbags' uncompressed McapWriter of rosbags "
                               "0.11; the run log's chunk writer needs it")
        if storage.chunk.bio.tell():
            raise RuntimeError("the bag's own pending chunk must be closed before the chunk writer takes over")
        self._bag, self._storage = bag, storage
        self._messages: list[tuple[int, int, bytes | bytearray]] = []
        self._size = 0                  # bytes of the pending message records

    @property
    def pending(self) -> int:
        """Messages waiting for the next chunk."""
        return len(self._messages)

    def add(self, channel_id: int, time_ns: int, data: bytes | bytearray) -> None:
        """Queue one message (CDR bytes ``data``) on channel ``channel_id`` at log time ``time_ns``."""
        self._messages.append((channel_id, time_ns, data))
        self._size += _MESSAGE_HEAD.size + len(data)
        if self._size > CHUNK_LIMIT:
            self._write_chunk()

    def flush(self) -> None:
        """Write the pending messages as one chunk (if any) and hand the file's buffer to the OS."""
        if self._messages:
            self._write_chunk()
        self._storage.bio.flush()

    def _write_chunk(self) -> None:
        messages, self._messages, self._size = self._messages, [], 0
        head = _MESSAGE_HEAD.pack
        parts = [b""]
        index: dict[int, list[int]] = {}     # channel -> [time, offset, time, offset, ...]
        pos = 0
        start, end = 2**63 - 1, 0
        for cid, t, data in messages:
            n = len(data)
            parts.append(head(OP_MESSAGE, _MESSAGE_FIELDS + n, cid, 0, t, t))
            parts.append(data)
            entries = index.get(cid)
            if entries is None:
                index[cid] = [t, pos]
            else:
                entries += (t, pos)
            pos += _MESSAGE_HEAD.size + n
            if t < start:
                start = t
            if t > end:
                end = t
        parts[0] = _CHUNK_HEAD.pack(OP_CHUNK, _CHUNK_FIELDS + pos, start, end, pos, 0, 0, pos)
        bio = self._storage.bio
        chunk_start = bio.tell()
        at = chunk_start + _CHUNK_HEAD.size + pos         # where the first Message Index record goes
        index_at = []
        index_size = 0
        for cid, entries in index.items():
            k = len(entries)
            parts.append(struct.pack(f"{_INDEX_HEAD}{k}Q", OP_MESSAGE_INDEX, 6 + 8 * k, cid, 8 * k, *entries))
            index_at.append(_CHANNEL_OFFSET.pack(cid, at + index_size))
            index_size += 15 + 8 * k
        bio.write(b"".join(parts))
        chunk_index = BytesIO()
        chunk_index.write(b"".join([
            _CHUNK_INDEX_HEAD.pack(start, end, chunk_start, _CHUNK_HEAD.size + pos, 10 * len(index)),
            *index_at, _CHUNK_INDEX_TAIL.pack(index_size, 0, pos, pos)]))
        self._account(chunk_index, index, start, end)

    def _account(self, chunk_index: BytesIO, index: dict[int, list[int]], start: int, end: int) -> None:
        """Give the chunk's index and message counts to the bag, for its summary and metadata.yaml."""
        storage, bag = self._storage, self._bag
        storage.chunks.append(chunk_index)
        stats, counts = storage.channel_stats, bag.counts
        for cid, entries in index.items():
            stats[cid] += len(entries) >> 1
            counts[cid] += len(entries) >> 1
        storage.message_start_time = min(start, storage.message_start_time)
        storage.message_end_time = max(end, storage.message_end_time)
        bag.min_timestamp = min(start, bag.min_timestamp)
        bag.max_timestamp = max(end, bag.max_timestamp)
