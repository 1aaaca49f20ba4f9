"""Byte-level behaviour on the pty: reply order, silence, bad CRC, wire timing (lower bounds only)."""
from __future__ import annotations

import time

import pytest
import serial

from swerve.driver import packets as pk
from swerve.driver.control_table import HardwareError, Reg
from swerve.driver.packets import ErrorNumber
from swerve.driver.parser import PacketParser
from swerve.emulator.server import LinkSettings
from swerve.emulator.factory import build_emulator
from swerve.emulator.timing import Frozen

QUIET_S = 0.15      # how long "no reply" is listened for


def _collect(port: serial.Serial, count: int, timeout_s: float = 3.0) -> list:
    """Up to ``count`` packets arriving before ``timeout_s``."""
    parser, got = PacketParser(), []
    deadline = time.monotonic() + timeout_s
    while len(got) < count and time.monotonic() < deadline:
        port.timeout = max(0.0, deadline - time.monotonic())
        chunk = port.read(1)
        chunk += port.read(port.in_waiting)
        got += parser.feed(chunk)
    return got


def _silent(port: serial.Serial) -> bool:
    port.timeout = QUIET_S
    return port.read(64) == b""


@pytest.fixture
def wire():
    with build_emulator(ids=range(1, 9), timing=Frozen()) as emu:
        with serial.Serial(emu.port, 1_000_000, timeout=1.0) as port:
            yield emu, port


def test_broadcast_ping_answers_in_ascending_id_order(wire):
    emu, port = wire
    port.write(pk.ping(pk.BROADCAST_ID).encode())
    assert [p.id for p in _collect(port, 8)] == list(range(1, 9))


def test_sync_and_bulk_read_reply_in_listed_order(wire):
    emu, port = wire
    port.write(pk.sync_read(132, 4, [7, 2, 5]).encode())
    assert [p.id for p in _collect(port, 3)] == [7, 2, 5]
    port.write(pk.bulk_read([(3, 132, 4), (1, 65, 1), (8, 146, 1)]).encode())
    replies = _collect(port, 3)
    assert [(p.id, len(p.params)) for p in replies] == [(3, 4), (1, 1), (8, 1)]


def test_fast_sync_read_is_one_frame_with_id_fe(wire):
    emu, port = wire
    for i in (3, 7, 4):
        emu.servo(i).write(Reg.PRESENT_POSITION, {3: 166, 7: 2079, 4: 1023}[i])
    port.write(bytes.fromhex("FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"))   # e-Manual
    port.timeout = 2.0
    frame = port.read(32)
    assert frame == bytes.fromhex("FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00"
                                  "16 CA 00 04 FF 03 00 00 D1 9E")


def test_no_reply_where_the_protocol_says_none(wire):
    emu, port = wire
    port.write(pk.write(pk.BROADCAST_ID, 65, b"\x01").encode())
    assert _silent(port)
    port.write(pk.sync_write(65, 1, {1: b"\x00", 2: b"\x00"}).encode())
    assert _silent(port)
    port.write(pk.read(pk.BROADCAST_ID, 65, 1).encode())
    assert _silent(port)
    assert [emu.servo(i).read(Reg.LED) for i in (1, 2, 3)] == [0, 0, 1]


def test_bad_crc_dropped_then_parser_resynchronises(wire):
    emu, port = wire
    bad = bytearray(pk.ping(1).encode())
    bad[-1] ^= 0xFF
    port.write(b"\x00\xff\xff" + bytes(bad) + b"\xfd\x00garbage" + pk.ping(2).encode())
    replies = _collect(port, 2, timeout_s=1.0)
    assert [p.id for p in replies] == [2]
    assert emu.stats.bad_frames >= 1


def test_crc_error_reply_option():
    with build_emulator(ids=[1], timing=Frozen(), link=LinkSettings(crc_error_reply=True)) as emu:
        with serial.Serial(emu.port, 1_000_000, timeout=1.0) as port:
            bad = bytearray(pk.ping(1).encode())
            bad[-1] ^= 0xFF
            port.write(bytes(bad))
            (reply,) = _collect(port, 1)
            assert (reply.id, reply.error) == (1, ErrorNumber.CRC)


def test_partial_frame_abandoned_after_idle_gap(wire):
    emu, port = wire
    frame = pk.ping(3).encode()
    port.write(frame[:6])
    time.sleep(0.05)                          # far longer than the 1.5 ms inter-byte limit
    port.write(frame[6:] + pk.ping(4).encode())
    assert [p.id for p in _collect(port, 2, timeout_s=1.0)] == [4]


def test_input_voltage_error_sets_alert_but_keeps_torque(wire):
    emu, port = wire
    emu.servo(2).write(Reg.TORQUE_ENABLE, 1)
    emu.faults.raise_hardware_error(2, HardwareError.INPUT_VOLTAGE)   # not in Shutdown (52)
    port.write(pk.read(2, 70, 1).encode())
    (reply,) = _collect(port, 1)
    assert reply.alert and reply.params == bytes((HardwareError.INPUT_VOLTAGE,))
    assert emu.servo(2).read(Reg.TORQUE_ENABLE) == 1
    emu.faults.raise_hardware_error(2, "overheating+encoder")
    assert emu.servo(2).read(Reg.TORQUE_ENABLE) == 0
    assert emu.servo(2).read(Reg.HARDWARE_ERROR_STATUS) == 0x0D


def test_wire_timing_costs_at_least_the_wire_time():
    baud = 57_600
    with build_emulator(ids=range(1, 9), baud=baud, timing=Frozen(), link=LinkSettings(wire_timing=True)) as emu:
        for s in emu.servos:
            s.write(Reg.RETURN_DELAY_TIME, 0)
        with serial.Serial(emu.port, baud, timeout=2.0) as port:
            request = pk.sync_read(132, 4, range(1, 9)).encode()
            nbytes = len(request) + 8 * 15
            best = float("inf")
            for _ in range(3):
                port.reset_input_buffer()
                t = time.monotonic()
                port.write(request)
                assert len(_collect(port, 8)) == 8
                best = min(best, time.monotonic() - t)
            assert best >= 0.95 * nbytes * 10 / baud     # 142 bytes at 57600 bps = 24.7 ms
