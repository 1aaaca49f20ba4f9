"""A client's output flush (``tcflush(fd, TCOFLUSH)``, as pypot does before every packet) is
seen through the pty's packet mode, counted, and said once on stderr."""
from __future__ import annotations

import os
import select
import termios
import tty

import pytest

from swerve.driver.packets import InstructionPacket, Instruction, StatusPacket
from swerve.driver.parser import PacketParser
from swerve.emulator.pty_link import PtyLink
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import OUTPUT_FLUSH_NOTICE

PING_1 = InstructionPacket(1, Instruction.PING).encode()


def _open_client(path: str) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    return fd


def _read_ready(link: PtyLink) -> bytes:
    """The next read of the master once it has something (a generous bound, not a timing check)."""
    assert select.select([link.master], [], [], 10.0)[0]
    return link.read()


def _round_trip(fd: int, frame: bytes) -> StatusPacket:
    """Write ``frame`` and block until one status packet comes back."""
    os.write(fd, frame)
    parser = PacketParser()
    while True:
        packets = parser.feed(os.read(fd, 256))
        if packets:
            return packets[0]


def test_a_flush_is_counted_and_later_bytes_arrive_whole():
    seen = []
    link = PtyLink(on_output_flush=lambda: seen.append(link.output_flushes))
    fd = _open_client(link.path)
    try:
        os.write(fd, PING_1)                         # nobody reads the master yet
        termios.tcflush(fd, termios.TCOFLUSH)        # what pypot does before each packet
        assert _read_ready(link) == b""               # the status read: no data
        assert (link.output_flushes, seen) == (1, [1])
        # the kernel discards what is still in the pty's buffer; bytes its worker has already
        # handed to the master's line discipline survive (so a flushed ping may or may not come)
        assert link.read() in (b"", PING_1)
        os.write(fd, PING_1)
        assert _read_ready(link) == PING_1            # later bytes arrive whole, without the prefix
        assert link.output_flushes == 1
    finally:
        os.close(fd)
        link.close()


@pytest.mark.parametrize("flushes", [1, 3])
def test_emulator_counts_flushes_says_so_once_and_keeps_serving(flushes, capfd):
    with build_emulator(ids=[1], baud=1_000_000) as emu:
        fd = _open_client(emu.port)
        try:
            for k in range(flushes):
                assert _round_trip(fd, PING_1).id == 1   # the emulator has read everything sent
                termios.tcflush(fd, termios.TCOFLUSH)
            # the reply to this ping shows the emulator has taken the flush status before it
            assert _round_trip(fd, PING_1).error == 0
        finally:
            os.close(fd)
        assert emu.stats.client_output_flushes == flushes
        assert emu.stats.packets_received == flushes + 1
    err = capfd.readouterr().err
    assert err.count(OUTPUT_FLUSH_NOTICE) == 1
