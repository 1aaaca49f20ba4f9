"""Incremental Protocol 2.0 frame parser (push style, no I/O).

Feed it byte chunks of any size; it returns every complete, CRC-valid packet, and
resynchronises on the next ``FF FF FD 00`` after garbage, a truncated frame or a bad CRC,
the way the servo firmware and the SDK's receive loop hunt for a header.
"""
from __future__ import annotations

import struct

from swerve.driver.errors import CorruptPacketError
from swerve.driver.packets import HEADER, MAX_LENGTH, Packet, decode_frame


class PacketParser:
    """Turn a byte stream into packets.

    ``feed(data)`` returns the packets completed by ``data``. Frames that fail their CRC or
    cannot be decoded are dropped; the reason is kept in :attr:`errors` (drain with
    :meth:`take_errors`) and counted, and parsing resumes *inside* the bad frame, so a good
    packet that a truncated one swallowed is still found.
    """

    def __init__(self, max_length: int = MAX_LENGTH):
        self._buf = bytearray()
        self.max_length = max_length
        self.errors: list[CorruptPacketError] = []
        self.dropped_bytes = 0
        self.bad_frames = 0

    @property
    def pending(self) -> int:
        """Bytes buffered that are not yet a complete packet."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget buffered bytes (e.g. before a new transaction)."""
        self.dropped_bytes += len(self._buf)
        self._buf.clear()

    def take_errors(self) -> list[CorruptPacketError]:
        """Return and clear the errors seen since the last call."""
        errs, self.errors = self.errors, []
        return errs

    def feed(self, data: bytes) -> list[Packet]:
        """Append ``data`` and return the packets it completes, in order."""
        self._buf += data
        return self._drain()

    def flush(self) -> list[Packet]:
        """Give up on a partial frame at the front (its sender went silent) and rescan.

        Call when the line has been idle longer than an inter-byte gap allows; returns any
        complete packets found after the abandoned header. Afterwards nothing is pending: a
        partial frame or header prefix left over is stale once the line has gone idle.
        """
        out: list[Packet] = []
        while self._buf:
            self._drop(1)
            out += self._drain()
        return out

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        self.dropped_bytes += n

    def _drain(self) -> list[Packet]:
        out: list[Packet] = []
        buf = self._buf
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # keep a possible header prefix (up to 3 bytes) for the next chunk
                keep = next((k for k in (3, 2, 1)
                             if k <= len(buf) and HEADER.startswith(bytes(buf[-k:]))), 0)
                self._drop(len(buf) - keep)
                return out
            if start:
                self._drop(start)
            if len(buf) < 7:
                return out
            (length,) = struct.unpack_from("<H", buf, 5)
            if length < 3 or length > self.max_length:
                self.bad_frames += 1
                self.errors.append(CorruptPacketError(f"implausible LENGTH {length}; resynchronising"))
                self._drop(1)
                continue
            end = 7 + length
            if len(buf) < end:
                return out
            try:
                out.append(decode_frame(bytes(buf[:end])))
            except (CorruptPacketError, ValueError) as exc:
                self.bad_frames += 1
                self.errors.append(exc if isinstance(exc, CorruptPacketError)
                                   else CorruptPacketError(str(exc)))
                self._drop(1)  # resume the hunt inside the rejected frame
                continue
            del buf[:end]
