"""The counters of one emulated bus run (:class:`Stats`, ``emu.stats``)."""
from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class Stats:
    """Counters of one emulator run (read them any time; written by the bus thread)."""

    packets_received: int = 0      # instruction packets decoded
    replies_sent: int = 0          # status frames (or fast-read slices) written
    replies_dropped: int = 0       # by fault injection
    replies_corrupted: int = 0     # by fault injection
    bad_frames: int = 0            # bad CRC / implausible length (parser)
    dropped_bytes: int = 0         # garbage and abandoned partial frames (parser)
    status_packets_ignored: int = 0  # status frames on the line (another device talking)
    malformed_packets: int = 0     # valid frames whose parameters make no sense (ignored)
    dispatch_errors: int = 0       # unexpected exceptions caught while handling one packet
    wrong_baud_packets: int = 0    # no servo listens at the client's line speed
    tx_overflow_bytes: int = 0     # reply bytes the pty would not take (client not reading)
    client_output_flushes: int = 0  # client tcflush(TCOFLUSH) calls seen (pty packet mode); each
                                    # discards what the emulator had not read: how much is unknown
    clock_ticks: int = 0           # physics steps (clock and advance)

    def as_dict(self) -> dict[str, int]:
        return asdict(self)
