"""Fixtures for the emulator tests: a running :class:`Emulator` and two bus clients.

``client`` is parametrised over the unmodified dynamixel-sdk 4.1 (``sdk``) and the project's
own :class:`driver.bus.Bus` (``driver``). Both adapters speak raw bytes and report the status
ERR byte instead of raising, so one test body checks both against the same expectations.
``TIMEOUT`` means "no (valid) reply".
"""
from __future__ import annotations

import sys
import time

import pytest

from swerve.driver.control_table import Reg, models, table_for
from swerve.emulator.factory import build_emulator

TIMEOUT = "timeout"
MODEL = "xh430-w210"
TABLE = table_for(MODEL)


def valid_value(reg, servo) -> int:
    """A valid raw value for ``reg`` different from its default where possible."""
    special = {Reg.TORQUE_ENABLE: 1, Reg.LED: 1, Reg.STATUS_RETURN_LEVEL: 2, Reg.BUS_WATCHDOG: 0}
    if reg.name in special:
        return special[reg.name]
    lo, hi = reg.raw_bounds()
    v = lo + (hi - lo) // 3
    if reg.limit:
        cap = servo.read(reg.limit)
        v = max(-cap, min(cap, v))
    if reg.limit_min:
        v = max(servo.read(reg.limit_min), min(servo.read(reg.limit_max), v))
    return v


def check_reads_match(read, table, servo) -> None:
    """``read(reg) -> (data, status error)`` of every item of ``table`` answers without error
    and agrees with ``servo``'s memory (Realtime Tick excepted: the clock moves it); a read is
    repeated while it times out (:func:`answered`)."""
    for reg in table:
        got = answered(read, reg)
        assert got != TIMEOUT, reg.name
        data, err = got
        assert err == 0, reg.name
        if reg.name != Reg.REALTIME_TICK:
            assert reg.decode(bytes(data)) == servo.read(reg.name), reg.name


#: GIL switch interval while an in-process emulator runs, s. The SDK's receive loop spins
#: (timeout=0 polling) and holds the GIL; at the default 5 ms hand-over the emulator thread,
#: which needs the GIL a few times per reply, could miss the SDK's 34 ms packet timeout.
SWITCH_INTERVAL_S = 1e-4


@pytest.fixture
def emulator():
    """A running 8-servo XH430-W210 bus at 1 Mbps (IDs 1-8), in this process."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        with build_emulator(ids=range(1, 9), model=MODEL, baud=1_000_000) as emu:
            yield emu
    finally:
        sys.setswitchinterval(previous)


#: The SDK's hard-coded FTDI latency budget is 16 ms (packet timeout = 2*16 + 2 ms + bytes).
#: The in-process emulator shares the CPU and the GIL with the SDK's spinning receive loop and
#: with whatever else runs on a loaded 2-core machine, so tests give it the budget of a slow
#: adapter instead: a reply up to ~400 ms late still counts, and each expected silence costs
#: ~0.4 s. Only this module constant is set; the SDK's code runs unmodified.
SDK_LATENCY_TIMER_MS = 200
#: The same allowance for the project's driver (slack added to its computed reply timeout).
DRIVER_MARGIN_S = 0.4
#: Hang guard of :func:`answered`, s.
ANSWER_WAIT_S = 60.0


def answered(call, *args):
    """``call(*args)`` repeated while it returns ``TIMEOUT`` (at most :data:`ANSWER_WAIT_S`), for an
    idempotent request that must be answered: a host loaded beyond the clients' wall-clock reply
    budget delays an answer past it, and the verdict is on the answer, not on when it came."""
    deadline = time.monotonic() + ANSWER_WAIT_S
    while True:
        got = call(*args)
        if got != TIMEOUT or time.monotonic() > deadline:
            return got


class SdkClient:
    """dynamixel-sdk 4.1 used exactly as its examples do."""

    name = "sdk"

    def __init__(self, port: str, baud: int = 1_000_000):
        import dynamixel_sdk as sdk

        self.sdk = sdk
        self.port = sdk.PortHandler(port)
        self.ph = sdk.PacketHandler(2.0)
        assert self.port.openPort()
        assert self.port.setBaudRate(baud)

    def close(self) -> None:
        self.port.closePort()

    def _ok(self, result: int) -> bool:
        return result == self.sdk.COMM_SUCCESS

    def ping(self, id_):
        model, result, err = self.ph.ping(self.port, id_)
        return (model, err) if self._ok(result) else TIMEOUT

    def broadcast_ping(self) -> dict[int, int]:
        found, result = self.ph.broadcastPing(self.port)
        return {i: v[0] for i, v in found.items()}

    def read(self, id_, address, length):
        data, result, err = self.ph.readTxRx(self.port, id_, address, length)
        return (bytes(data), err) if self._ok(result) else TIMEOUT

    def write(self, id_, address, data):
        result, err = self.ph.writeTxRx(self.port, id_, address, len(data), list(data))
        return err if self._ok(result) else TIMEOUT

    def reg_write(self, id_, address, data):
        result, err = self.ph.regWriteTxRx(self.port, id_, address, len(data), list(data))
        return err if self._ok(result) else TIMEOUT

    def action(self, id_=0xFE):
        self.ph.action(self.port, id_)

    def reboot(self, id_):
        result, err = self.ph.reboot(self.port, id_)
        return err if self._ok(result) else TIMEOUT

    def factory_reset(self, id_, option):
        result, err = self.ph.factoryReset(self.port, id_, option)
        return err if self._ok(result) else TIMEOUT

    def clear(self, id_):
        result, err = self.ph.clearMultiTurn(self.port, id_)
        return err if self._ok(result) else TIMEOUT

    def sync_write(self, address, length, values: dict[int, bytes]) -> None:
        g = self.sdk.GroupSyncWrite(self.port, self.ph, address, length)
        for i, d in values.items():
            assert g.addParam(i, list(d))
        assert self._ok(g.txPacket())

    def bulk_write(self, items) -> None:
        g = self.sdk.GroupBulkWrite(self.port, self.ph)
        for i, address, d in items:
            assert g.addParam(i, address, len(d), list(d))
        assert self._ok(g.txPacket())

    def sync_read(self, ids, address, length, fast=False):
        g = self.sdk.GroupSyncRead(self.port, self.ph, address, length)
        for i in ids:
            assert g.addParam(i)
        result = g.fastSyncRead() if fast else g.txRxPacket()
        if not self._ok(result):
            return TIMEOUT
        return {i: g.getData(i, address, length) for i in ids}

    def bulk_read(self, items, fast=False):
        g = self.sdk.GroupBulkRead(self.port, self.ph)
        for i, address, length in items:
            assert g.addParam(i, address, length)
        result = g.fastBulkRead() if fast else g.txRxPacket()
        if not self._ok(result):
            return TIMEOUT
        return {i: g.getData(i, address, length) for i, address, length in items}


class DriverClient:
    """The project's :class:`driver.bus.Bus`, errors mapped back to ERR bytes."""

    name = "driver"

    def __init__(self, port: str, baud: int = 1_000_000):
        from swerve.driver.bus import Bus

        self.bus = Bus(port, baud, default_model=MODEL, timeout_margin_s=DRIVER_MARGIN_S)

    def close(self) -> None:
        self.bus.close()

    def _call(self, fn, *args):
        from swerve.driver.errors import CorruptPacketError, DxlTimeoutError, ServoError

        try:
            return fn(*args), 0
        except ServoError as exc:
            return None, exc.error_byte
        except (DxlTimeoutError, CorruptPacketError):
            return TIMEOUT, None

    def ping(self, id_):
        res, err = self._call(self.bus.ping, id_)
        return TIMEOUT if res == TIMEOUT else (res.model_number, err)

    def broadcast_ping(self) -> dict[int, int]:
        return {i: r.model_number for i, r in self.bus.broadcast_ping(range(1, 9)).items()}

    def read(self, id_, address, length):
        data, err = self._call(self.bus.read_bytes, id_, address, length)
        return TIMEOUT if data == TIMEOUT else (data, err)

    def _err(self, fn, *args):
        res, err = self._call(fn, *args)
        return TIMEOUT if res == TIMEOUT else err

    def write(self, id_, address, data):
        return self._err(self.bus.write_bytes, id_, address, bytes(data))

    def reg_write(self, id_, address, data):
        from swerve.driver import packets as pk

        return self._err(self.bus._with_retries, self.bus._simple, pk.reg_write(id_, address, bytes(data)))

    def action(self, id_=0xFE):
        self._call(self.bus.action, id_)

    def reboot(self, id_):
        return self._err(self.bus.reboot, id_)

    def factory_reset(self, id_, option):
        return self._err(self.bus.factory_reset, id_, option)

    def clear(self, id_):
        return self._err(self.bus.clear, id_)

    def _reg_at(self, address):
        return TABLE.at(address)

    def sync_write(self, address, length, values: dict[int, bytes]) -> None:
        reg = self._reg_at(address)
        assert reg.size == length
        self.bus.sync_write(reg.name, {i: reg.decode(bytes(d)) for i, d in values.items()})

    def bulk_write(self, items) -> None:
        regs = {}
        for i, address, d in items:
            reg = self._reg_at(address)
            regs[i] = {reg.name: reg.decode(bytes(d))}
        self.bus.bulk_write(regs)

    def _span(self, address, length):
        first = self._reg_at(address)
        last = [r for r in TABLE if r.address + r.size == address + length][0]
        return first.name, last.name

    def _unsigned(self, values: dict[str, int], address, length) -> int:
        blob = b"".join(TABLE[n].encode(v) for n, v in sorted(values.items(), key=lambda kv: TABLE[kv[0]].address))
        return int.from_bytes(blob[:length], "little")

    def sync_read(self, ids, address, length, fast=False):
        first, last = self._span(address, length)
        got, err = self._call(self.bus.sync_read, list(ids), first, last, fast)
        if got == TIMEOUT or got is None:
            return TIMEOUT
        return {i: self._unsigned(v, address, length) for i, v in got.items()}

    def bulk_read(self, items, fast=False):
        spec = {i: self._span(a, n) for i, a, n in items}
        got, err = self._call(self.bus.bulk_read, spec, fast)
        if got == TIMEOUT or got is None:
            return TIMEOUT
        return {i: self._unsigned(got[i], a, n) for i, a, n in items}


CLIENTS = {"sdk": SdkClient, "driver": DriverClient}


@pytest.fixture(autouse=True)
def _sdk_latency(monkeypatch):
    import dynamixel_sdk.port_handler

    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", SDK_LATENCY_TIMER_MS)


@pytest.fixture(params=sorted(CLIENTS))
def client(request, emulator):
    """A bus client (dynamixel-sdk or the project's driver) opened on ``emulator`` at 1 Mbps."""
    c = CLIENTS[request.param](emulator.port)
    yield c
    c.close()


@pytest.fixture
def sdk_client(emulator):
    c = SdkClient(emulator.port)
    yield c
    c.close()


@pytest.fixture(params=sorted(models()))
def model_emulator(request):
    """A running register-only bus of four servos (IDs 1-4) of one shipped model at 1 Mbps,
    once per file in ``configs/models``."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        with build_emulator(ids=range(1, 5), model=request.param, baud=1_000_000) as emu:
            yield emu
    finally:
        sys.setswitchinterval(previous)
