"""A client's output flush (``tcflush(fd, TCOFLUSH)``, as pypot does before every packet) is
seen through the pty's packet mode, counted, and said once on stderr."""
from __future__ import annotations

import os
import termios
import tty

import pytest

from swerve.driver.packets import InstructionPacket, Instruction, StatusPacket
from swerve.driver.parser import PacketParser
from swerve.emulator.pty_link import PtyLink
from swerve.emulator.robot_emulator import build_emulator
from swerve.emulator.server import OUTPUT_FLUSH_NOTICE

PING_1 = InstructionPacket(1, Instruction.PING).encode()


def _open_client(path: str) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    return fd


def _round_trip(fd: int, frame: bytes) -> StatusPacket:
    """Write ``frame`` and block until one status packet comes back."""
    os.write(fd, frame)
    parser = PacketParser()
    while True:
        packets = parser.feed(os.read(fd, 256))
        if packets:
            return packets[0]


def test_flushed_bytes_never_reach_the_master_and_the_flush_is_counted():
    seen = []
    link = PtyLink(on_output_flush=lambda: seen.append(link.output_flushes))
    fd = _open_client(link.path)
    try:
        os.write(fd, PING_1)                         # nobody reads the master yet
        termios.tcflush(fd, termios.TCOFLUSH)        # what pypot does before each packet
        assert link.read() == b""                     # the status read: no data
        assert (link.output_flushes, seen) == (1, [1])
        assert link.read() == b""                     # the ping was discarded by the kernel
        os.write(fd, PING_1)
        assert link.read() == PING_1                  # later bytes arrive whole, without the prefix
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
