"""Incremental Protocol 2.0 frame parser (push style, no I/O).

Feed it byte chunks of any size; it returns every complete, CRC-valid packet, decoded by
:func:`swerve.driver.packets.decode_frame` (the one decode path), and resynchronises on
the next ``FF FF FD 00`` after garbage, a truncated frame or a bad CRC, the way the servo
firmware and the SDK's receive loop hunt for a header.

Work is linear in the input, whatever the bytes: a candidate header is rejected from its
first eight bytes when its ID or LENGTH is impossible (LENGTH above
:data:`~swerve.driver.protocol.MAX_LENGTH`, the SDK's 1024-byte packet limit), and a
stuffed frame is rejected as soon as a second header shows up inside its body (byte
stuffing makes ``FF FF FD 00`` impossible there), before its CRC is computed. The next
search then starts at that second header, so no byte is searched or checksummed more
than a bounded number of times; :attr:`PacketParser.scanned_bytes` counts the work.

Replies known in advance (a Sync Read's statuses, :meth:`PacketParser.expect_statuses`) are
checked by :meth:`~swerve.driver.packets.ExpectedStatus.decode` when a whole frame of one is
at the front: a compare of its cached head and the CRC of its data continued from the head's.
That shortcut accepts exactly the frames the general path above would decode to the same
packet, and counts the same work; any other frame takes the general path.
"""
from __future__ import annotations

from collections import deque
from typing import Mapping, Sequence

from swerve.driver.errors import CorruptPacketError
from swerve.driver.packets import (STATUS_HEAD_BYTES, ExpectedStatus, FastStatus, Packet, decode_frame,
                                   fast_entries, fast_status_length)
from swerve.driver.protocol import BROADCAST_ID, HEADER, MAX_ID, MAX_LENGTH, PREFIX_BYTES, Instruction

_STATUS = int(Instruction.STATUS)
_CRC_BYTES = 2
#: Bytes of a status frame besides its data (head and CRC).
_STATUS_OVERHEAD = STATUS_HEAD_BYTES + _CRC_BYTES
#: Rejection reasons kept between :meth:`PacketParser.take_errors` calls (all are counted).
MAX_KEPT_ERRORS = 64


class PacketParser:
    """Turn a byte stream into packets.

    ``feed(data)`` returns the packets completed by ``data``. Frames that fail their CRC or
    cannot be decoded are dropped; the reason is kept in :attr:`errors` (drain with
    :meth:`take_errors`; the latest :data:`MAX_KEPT_ERRORS`) and counted, and parsing resumes *inside* the bad frame, so a good
    packet that a truncated one swallowed is still found.

    A combined Fast Sync/Bulk Read reply (status, ID 0xFE) is not byte-stuffed, so it can
    only be framed by its expected size: call :meth:`expect_fast` with the requested data
    lengths before the reply arrives; otherwise such a frame is rejected from its header.
    :meth:`expect_statuses` names ordinary statuses expected next, which are then decoded by
    their cached heads (the same packets, faster).
    """

    def __init__(self, max_length: int = MAX_LENGTH):
        self._buf = bytearray()
        self.max_length = max_length
        self.errors: deque[CorruptPacketError] = deque(maxlen=MAX_KEPT_ERRORS)
        self.dropped_bytes = 0
        self.bad_frames = 0
        #: Bytes examined by header searches and CRC checks since creation (a work counter).
        self.scanned_bytes = 0
        self._clean_to = 0           # buf[1:_clean_to] of the frame at buf[0] holds no header
        self._fast_lengths: tuple[int, ...] | None = None
        self._fast_length = -1
        #: Entries of an expected fast read reply that were complete and CRC-valid when
        #: :meth:`flush` abandoned it (the servos after them never sent); ``None`` if none.
        self.fast_entries_received: int | None = None
        self._expected: Mapping[int, ExpectedStatus] = {}

    @property
    def pending(self) -> int:
        """Bytes buffered that are not yet a complete packet."""
        return len(self._buf)

    def expect_fast(self, lengths: Sequence[int] | None) -> None:
        """Accept a combined fast read reply with data ``lengths`` per servo (``None``: none)."""
        if lengths is None:
            self._fast_lengths, self._fast_length = None, -1
        else:
            self._fast_lengths = tuple(lengths)
            self._fast_length = fast_status_length(self._fast_lengths)

    def expect_statuses(self, statuses: Mapping[int, ExpectedStatus] | None) -> None:
        """Decode the expected error-free statuses ``{id: ExpectedStatus}`` by their cached heads
        until the next call; ``None``: none. A status longer than :attr:`max_length` allows is
        left to the general path, which rejects it."""
        self._expected = {} if statuses is None else statuses

    def reset(self) -> None:
        """Forget buffered bytes (e.g. before a new transaction)."""
        self._drop(len(self._buf))
        self.fast_entries_received = None

    def take_errors(self) -> list[CorruptPacketError]:
        """Return and clear the errors seen since the last call."""
        errs = list(self.errors)
        self.errors.clear()
        return errs

    def feed(self, data: bytes) -> list[Packet | FastStatus]:
        """Append ``data`` and return the packets it completes, in order."""
        self._buf += data
        return self._drain()

    def flush(self) -> list[Packet | FastStatus]:
        """Give up on a partial frame at the front (its sender went silent) and rescan.

        Call when the line has been idle longer than an inter-byte gap allows; returns any
        complete packets found after the abandoned header. Afterwards nothing is pending: a
        partial frame or header prefix left over is stale once the line has gone idle.
        """
        out: list[Packet | FastStatus] = []
        self._count_fast_entries()
        while self._buf:
            self._drop(max(1, self._clean_to - 3))
            out += self._drain()
        return out

    def _count_fast_entries(self) -> None:
        """Set :attr:`fast_entries_received` when the front frame is an expected fast reply cut short."""
        buf, lengths = self._buf, self._fast_lengths
        if (lengths is None or len(buf) <= PREFIX_BYTES or not buf.startswith(HEADER)
                or buf[4] != BROADCAST_ID or buf[PREFIX_BYTES] != _STATUS):
            return
        k = 0
        for _, end, crc in fast_entries(buf, lengths):
            if crc != buf[end] | buf[end + 1] << 8:
                break
            k += 1
        self.fast_entries_received = k

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        self.dropped_bytes += n
        self._clean_to = 0

    def _reject(self, reason: str | CorruptPacketError, skip: int) -> None:
        self.bad_frames += 1
        self.errors.append(reason if isinstance(reason, CorruptPacketError)
                           else CorruptPacketError(reason))
        self._drop(skip)

    def _drain(self) -> list[Packet | FastStatus]:
        out: list[Packet | FastStatus] = []
        buf = self._buf
        header, prefix = HEADER, PREFIX_BYTES
        while True:
            n = len(buf)
            if not n:
                return out
            if not buf.startswith(header):
                start = buf.find(header)
                if start < 0:
                    self.scanned_bytes += n
                    # keep a possible header prefix (up to 3 bytes) for the next chunk
                    keep = next((k for k in (3, 2, 1) if buf.endswith(header[:k])), 0)
                    if n > keep:
                        self._drop(n - keep)
                    return out
                self.scanned_bytes += start
                self._drop(start)
                n -= start
            if n <= prefix:
                return out
            id_ = buf[4]
            expected = self._expected.get(id_)
            if expected is not None and not self._clean_to and expected.length + 4 <= self.max_length:
                pkt = expected.decode(buf)
                if pkt is not None:
                    # the work the general path counts for a whole frame found at the front: the
                    # header search of its body (bytes 1 .. end - 2), then the CRC over all of it
                    end = len(pkt.params) + _STATUS_OVERHEAD
                    self.scanned_bytes += 2 * end - 3
                    out.append(pkt)
                    del buf[:end]
                    continue
            length = buf[5] | buf[6] << 8
            fast = id_ == BROADCAST_ID and buf[prefix] == _STATUS
            if id_ > MAX_ID and id_ != BROADCAST_ID:
                self._reject(f"invalid ID {id_} in header; resynchronising", 1)
                continue
            if length < 3 or length > self.max_length:
                self._reject(f"implausible LENGTH {length}; resynchronising", 1)
                continue
            if fast and length != self._fast_length:
                self._reject(f"combined fast read reply of LENGTH {length} was not requested"
                             + (f" (expected {self._fast_length})" if self._fast_length > 0 else ""), 1)
                continue
            end = prefix + length
            if not fast:
                # byte stuffing keeps FF FF FD 00 out of a frame's body: a header there means
                # this frame is bogus or cut short, and the next one starts at that header
                limit = end - _CRC_BYTES if n > end - _CRC_BYTES else n
                clean = self._clean_to
                frm = clean - 3 if clean > 4 else 1
                if limit - frm >= 4:
                    p = buf.find(header, frm, limit)
                    if p >= 0:
                        self.scanned_bytes += p + 4 - frm
                        self._reject(f"header inside a {length}-byte frame body; resynchronising", p)
                        continue
                    self.scanned_bytes += limit - frm
                if limit > clean:
                    self._clean_to = limit
            if n < end:
                return out
            self.scanned_bytes += end
            try:
                pkt = decode_frame(bytes(buf[:end]), self._fast_lengths)
            except (CorruptPacketError, ValueError) as exc:
                # no header starts before _clean_to - 3: resume the hunt there
                self._reject(exc if isinstance(exc, CorruptPacketError) else CorruptPacketError(str(exc)),
                             max(1, self._clean_to - 3))
                continue
            out.append(pkt)
            del buf[:end]
            self._clean_to = 0
