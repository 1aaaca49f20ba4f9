"""Golden test: ``driver.packets`` builds byte-for-byte what dynamixel-sdk 4.1 sends.

The SDK is pointed at the slave side of a pty; what it writes is read from the master and
compared with our builder for the same call. Calls that wait for a reply (ping, reboot,
factory reset, clear, TxRx variants) time out on the silent pty after ~34 ms; only the
bytes matter here.
"""
from __future__ import annotations

import os
import pty
import select
import tty

import pytest

dxl = pytest.importorskip("dynamixel_sdk")

from swerve.driver import packets as pk  # noqa: E402

STUFFED = [0xFF, 0xFF, 0xFD, 0xFF]  # data that needs byte stuffing


@pytest.fixture(scope="module")
def sdk():
    master, slave = pty.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    port = dxl.PortHandler(os.ttyname(slave))
    assert port.openPort()
    assert port.setBaudRate(1_000_000)
    ph = dxl.PacketHandler(2.0)
    yield port, ph, master
    port.closePort()
    os.close(master)
    os.close(slave)


def _drain(fd: int) -> bytes:
    out = b""
    while select.select([fd], [], [], 0.05)[0]:
        out += os.read(fd, 4096)
    return out


def _sync_write(port, ph):
    g = dxl.GroupSyncWrite(port, ph, 116, 4)
    g.addParam(1, [0x96, 0, 0, 0])
    g.addParam(2, [0xAA, 0, 0, 0])
    g.txPacket()


def _bulk_write(port, ph):
    g = dxl.GroupBulkWrite(port, ph)
    g.addParam(1, 104, 4, [0x2A, 0, 0, 0])
    g.addParam(5, 116, 4, [0x00, 0x08, 0, 0])
    g.txPacket()


def _sync_read(fast):
    def call(port, ph):
        g = dxl.GroupSyncRead(port, ph, 126, 10)
        for i in (1, 2, 3, 4, 5, 6, 7, 8):
            g.addParam(i)
        (g.fastSyncReadTxPacket if fast else g.txPacket)()
    return call


def _bulk_read(fast):
    def call(port, ph):
        g = dxl.GroupBulkRead(port, ph)
        g.addParam(3, 132, 4)
        g.addParam(7, 124, 2)
        g.addParam(4, 146, 1)
        (g.fastBulkReadTxPacket if fast else g.txPacket)()
    return call


CASES = [
    ("ping", lambda p, h: h.ping(p, 1), pk.ping(1)),
    ("read4ByteTx", lambda p, h: h.read4ByteTx(p, 1, 132), pk.read(1, 132, 4)),
    ("readTxRx", lambda p, h: h.readTxRx(p, 7, 126, 10), pk.read(7, 126, 10)),
    ("write1ByteTxOnly", lambda p, h: h.write1ByteTxOnly(p, 3, 64, 1), pk.write(3, 64, b"\x01")),
    ("write2ByteTxRx", lambda p, h: h.write2ByteTxRx(p, 2, 84, 900), pk.write(2, 84, (900).to_bytes(2, "little"))),
    ("write4ByteTxOnly", lambda p, h: h.write4ByteTxOnly(p, 1, 116, 512), pk.write(1, 116, (512).to_bytes(4, "little"))),
    ("write4ByteTxOnly negative", lambda p, h: h.write4ByteTxOnly(p, 4, 104, (-42) & 0xFFFFFFFF),
     pk.write(4, 104, (-42).to_bytes(4, "little", signed=True))),
    ("writeTxOnly stuffed", lambda p, h: h.writeTxOnly(p, 1, 116, 4, STUFFED), pk.write(1, 116, bytes(STUFFED))),
    ("write broadcast", lambda p, h: h.write1ByteTxOnly(p, 0xFE, 64, 0), pk.write(0xFE, 64, b"\x00")),
    ("regWriteTxOnly", lambda p, h: h.regWriteTxOnly(p, 1, 104, 4, [200, 0, 0, 0]),
     pk.reg_write(1, 104, bytes([200, 0, 0, 0]))),
    ("regWriteTxRx", lambda p, h: h.regWriteTxRx(p, 6, 116, 4, STUFFED), pk.reg_write(6, 116, bytes(STUFFED))),
    ("action", lambda p, h: h.action(p, 1), pk.action(1)),
    ("action broadcast", lambda p, h: h.action(p, 0xFE), pk.action(0xFE)),
    ("reboot", lambda p, h: h.reboot(p, 1), pk.reboot(1)),
    ("factoryReset 0x01", lambda p, h: h.factoryReset(p, 1, 0x01), pk.factory_reset(1, 0x01)),
    ("factoryReset 0x02", lambda p, h: h.factoryReset(p, 8, 0x02), pk.factory_reset(8, 0x02)),
    ("factoryReset 0xFF", lambda p, h: h.factoryReset(p, 2, 0xFF), pk.factory_reset(2, 0xFF)),
    ("clearMultiTurn", lambda p, h: h.clearMultiTurn(p, 1), pk.clear(1)),
    ("GroupSyncRead.txPacket", _sync_read(False), pk.sync_read(126, 10, range(1, 9))),
    ("GroupSyncRead.fastSyncReadTxPacket", _sync_read(True), pk.sync_read(126, 10, range(1, 9), fast=True)),
    ("syncReadTx", lambda p, h: h.syncReadTx(p, 132, 4, [1, 2], 2, False), pk.sync_read(132, 4, [1, 2])),
    ("GroupSyncWrite.txPacket", _sync_write, pk.sync_write(116, 4, {1: b"\x96\0\0\0", 2: b"\xaa\0\0\0"})),
    ("syncWriteTxOnly stuffed", lambda p, h: h.syncWriteTxOnly(p, 116, 4, [1] + STUFFED, 5),
     pk.sync_write(116, 4, {1: bytes(STUFFED)})),
    ("GroupBulkRead.txPacket", _bulk_read(False), pk.bulk_read([(3, 132, 4), (7, 124, 2), (4, 146, 1)])),
    ("GroupBulkRead.fastBulkReadTxPacket", _bulk_read(True),
     pk.bulk_read([(3, 132, 4), (7, 124, 2), (4, 146, 1)], fast=True)),
    ("GroupBulkWrite.txPacket", _bulk_write, pk.bulk_write([(1, 104, b"\x2a\0\0\0"), (5, 116, b"\0\x08\0\0")])),
]


#: dynamixel-sdk 4.1 ``txPacket`` ignores the list ``addStuffing`` returns when a packet
#: grows (it rebinds a local name), so frames that need stuffing go out UNSTUFFED with the
#: old LENGTH and a CRC over unstuffed bytes. Ours follow the protocol; see
#: test_sdk_add_stuffing_agrees for the SDK's own stuffing routine agreeing with us.
SDK_STUFFING_BUG = {"writeTxOnly stuffed", "regWriteTxRx", "syncWriteTxOnly stuffed"}


def _params():
    for name, call, expected in CASES:
        marks = [pytest.mark.xfail(strict=True, reason="SDK 4.1 sends unstuffed frames")] \
            if name in SDK_STUFFING_BUG else []
        yield pytest.param(call, expected, id=name, marks=marks)


@pytest.mark.parametrize("call, expected", list(_params()))
def test_same_bytes_as_sdk(sdk, call, expected):
    port, ph, master = sdk
    _drain(master)
    port.is_using = False  # Tx-only calls leave the SDK's busy flag set for the matching Rx
    call(port, ph)
    assert _drain(master).hex(" ") == expected.encode().hex(" ")


def test_broadcast_ping_same_bytes(sdk):
    """broadcastPing listens ~0.8 s for replies; the request is our broadcast ping."""
    port, ph, master = sdk
    _drain(master)
    port.is_using = False
    ph.broadcastPing(port)
    assert _drain(master) == pk.ping(pk.BROADCAST_ID).encode()


@pytest.mark.parametrize("pkt", [pk.write(1, 116, bytes(STUFFED)), pk.reg_write(6, 116, bytes(STUFFED)),
                                 pk.sync_write(116, 4, {1: bytes(STUFFED)})], ids=["write", "reg_write", "sync_write"])
def test_sdk_add_stuffing_agrees(sdk, pkt):
    """Where the SDK drops its own stuffing, its ``addStuffing`` result still equals our frame."""
    _, ph, _ = sdk
    body = bytes((pkt.instruction,)) + pkt.params
    raw = list(pk.HEADER + bytes((pkt.id,)) + (len(body) + 2).to_bytes(2, "little") + body + b"\0\0")
    stuffed = ph.addStuffing(raw)
    n = stuffed[5] | stuffed[6] << 8
    frame = bytes(stuffed[:5 + 2 + n - 2])
    crc = ph.updateCRC(0, list(frame), len(frame))
    assert (frame + crc.to_bytes(2, "little")).hex(" ") == pkt.encode().hex(" ")


def test_sdk_sends_unstuffed_frame(sdk):
    """Documents the SDK bug: the wire bytes are the unstuffed frame (LENGTH 9, CRC over it)."""
    port, ph, master = sdk
    _drain(master)
    port.is_using = False
    ph.writeTxOnly(port, 1, 116, 4, STUFFED)
    body = bytes((pk.Instruction.WRITE,)) + (116).to_bytes(2, "little") + bytes(STUFFED)
    frame = pk.HEADER + b"\x01" + (len(body) + 2).to_bytes(2, "little") + body
    assert _drain(master) == frame + pk.crc16(frame).to_bytes(2, "little")
