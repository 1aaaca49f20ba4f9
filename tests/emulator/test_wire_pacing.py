"""Wire timing never delivers a reply before the cable could (lower bounds only: load only delays)."""
from __future__ import annotations

import time

import serial

from swerve.driver import packets as pk
from swerve.driver.control_table import Reg
from swerve.driver.parser import PacketParser
from swerve.emulator.server import LinkSettings
from swerve.emulator.factory import build_emulator
from swerve.emulator.timing import Frozen

BAUD = 1_000_000
STATUS_BYTES = 11 + 4            # status of a 4-byte read


def _arrivals(port: serial.Serial, request: bytes, count: int) -> tuple[float, list[tuple[int, float]]]:
    """Send ``request``; (monotonic time before the write, [(id, time the reply was read)])."""
    parser, got = PacketParser(), []
    port.reset_input_buffer()
    t0 = time.monotonic()
    port.write(request)
    deadline = t0 + 3.0
    while len(got) < count and time.monotonic() < deadline:
        port.timeout = max(0.0, deadline - time.monotonic())
        chunk = port.read(1)
        chunk += port.read(port.in_waiting)
        t = time.monotonic()
        got += [(p.id, t) for p in parser.feed(chunk)]
    return t0, got


def test_each_sync_read_reply_arrives_no_earlier_than_its_last_byte_on_the_wire():
    with build_emulator(ids=range(1, 9), baud=BAUD, timing=Frozen(), link=LinkSettings(wire_timing=True)) as emu:
        for s in emu.servos:
            s.write(Reg.RETURN_DELAY_TIME, 0)
        request = pk.sync_read(132, 4, range(1, 9)).encode()
        byte_s = 10 / BAUD
        with serial.Serial(emu.port, BAUD, timeout=2.0) as port:
            for _ in range(20):
                t0, got = _arrivals(port, request, 8)
                assert [i for i, _ in got] == list(range(1, 9))
                for k, (id_, t) in enumerate(got):
                    earliest_s = (len(request) + (k + 1) * STATUS_BYTES) * byte_s
                    assert t - t0 >= earliest_s, f"reply {k + 1} (ID {id_}) after {(t - t0) * 1e6:.0f} us"


def test_return_delay_spaces_the_replies_without_wire_timing():
    with build_emulator(ids=range(1, 4), baud=BAUD, timing=Frozen()) as emu:
        for s in emu.servos:
            s.write(Reg.RETURN_DELAY_TIME, 250)          # 500 us
        request = pk.sync_read(132, 4, range(1, 4)).encode()
        with serial.Serial(emu.port, BAUD, timeout=2.0) as port:
            for _ in range(5):
                t0, got = _arrivals(port, request, 3)
                assert [i for i, _ in got] == [1, 2, 3]
                for k, (_, t) in enumerate(got):
                    assert t - t0 >= (k + 1) * 500e-6
