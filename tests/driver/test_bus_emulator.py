"""Bus over a real pty against the emulator (or the real bus with --port).

Tests that inject faults use the ``emu`` fixture and are skipped on hardware; the
wrong-ID / garbage cases use the scripted ``fake`` responder.
"""
from __future__ import annotations

import time

import pytest

from swerve.driver.bus import Bus, PingResult
from swerve.driver.control_table import HardwareError, Reg
from swerve.driver.errors import (CorruptPacketError, DxlTimeoutError, OutOfRangeError, RegisterError,
                           ServoError)
from swerve.driver.packets import ErrorNumber, Instruction

IDS = list(range(1, 9))


def _eventually(fn, timeout_s=2.0):
    """Poll a condition on the emulator's side (sync writes have no reply)."""
    deadline = time.monotonic() + timeout_s
    while True:
        if fn():
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)


def test_ping_identifies_model(bus):
    r = bus.ping(1)
    assert isinstance(r, PingResult)
    assert (r.id, r.model_number, r.model) == (1, 1010, "XH430-W210")
    assert r.firmware > 0
    assert bus.table(1).model == "XH430-W210"


def test_scan_finds_all_eight(bus):
    found = bus.scan(range(0, 10))
    assert [r.id for r in found] == IDS


def test_broadcast_ping(bus):
    assert sorted(bus.broadcast_ping(range(1, 9))) == IDS


def test_signed_write_read_roundtrip(bus):
    bus.write(2, Reg.TORQUE_ENABLE, 0)
    for raw in (-150, 0, 200):  # within the default Velocity Limit (210)
        bus.write(2, Reg.GOAL_VELOCITY, raw)
        assert bus.read(2, Reg.GOAL_VELOCITY) == raw
    bus.write(2, "goal_velocity", 0)


def test_si_roundtrip_and_range(bus):
    bus.write_si(3, Reg.GOAL_VELOCITY, -1.0)
    raw = bus.read(3, Reg.GOAL_VELOCITY)
    assert raw == round(-1.0 / 0.023980823922402087)
    assert bus.read_si(3, Reg.GOAL_VELOCITY) == pytest.approx(-1.0, abs=0.013)
    with pytest.raises(OutOfRangeError, match="goal_velocity"):
        bus.write_si(3, Reg.GOAL_VELOCITY, 100.0)  # rad/s   # rad/s: > 1023 units, not clamped
    bus.write(3, Reg.GOAL_VELOCITY, 0)


def test_bad_values_and_names_fail_before_sending(bus):
    with pytest.raises(OutOfRangeError):
        bus.write(1, Reg.GOAL_VELOCITY, 5000)
    with pytest.raises(RegisterError, match="goal_speed"):
        bus.read(1, "goal_speed")
    with pytest.raises(RegisterError, match="read-only"):
        bus.write(1, Reg.PRESENT_POSITION, 0)
    with pytest.raises(ValueError):
        bus.ping(300)


def test_sync_read_span(bus):
    out = bus.sync_read(IDS, Reg.PRESENT_CURRENT, Reg.PRESENT_POSITION)
    assert sorted(out) == IDS
    assert set(out[1]) == {"present_current", "present_velocity", "present_position"}


def test_sync_write_then_sync_read_and_fast(bus):
    bus.sync_write(Reg.PROFILE_VELOCITY, {i: 10 * i for i in IDS})
    for fast in (False, True):
        got = bus.sync_read(IDS, Reg.PROFILE_VELOCITY, fast=fast)
        assert {i: v["profile_velocity"] for i, v in got.items()} == {i: 10 * i for i in IDS}
    bus.sync_write(Reg.PROFILE_VELOCITY, {i: 0 for i in IDS})


def test_bulk_write_and_bulk_read(bus):
    bus.sync_write(Reg.TORQUE_ENABLE, {i: 0 for i in IDS})
    bus.bulk_write({1: {Reg.GOAL_VELOCITY: -7}, 5: {Reg.PROFILE_ACCELERATION: 3, Reg.PROFILE_VELOCITY: 9}})
    for fast in (False, True):
        got = bus.bulk_read({1: Reg.GOAL_VELOCITY, 5: (Reg.PROFILE_ACCELERATION, Reg.PROFILE_VELOCITY)},
                            fast=fast)
        assert got == {1: {"goal_velocity": -7},
                       5: {"profile_acceleration": 3, "profile_velocity": 9}}
    bus.bulk_write({1: {Reg.GOAL_VELOCITY: 0}, 5: {Reg.PROFILE_ACCELERATION: 0, Reg.PROFILE_VELOCITY: 0}})


def test_bulk_write_rejects_non_contiguous(bus):
    with pytest.raises(ValueError, match="contiguous"):
        bus.bulk_write({1: {Reg.GOAL_VELOCITY: 0, Reg.GOAL_POSITION: 0}})


def test_reg_write_and_action(bus):
    bus.write(4, Reg.LED, 0)
    bus.reg_write(4, Reg.LED, 1)
    assert bus.read(4, Reg.LED) == 0
    bus.action()  # broadcast
    assert _eventually(lambda: bus.read(4, Reg.LED) == 1)
    bus.write(4, Reg.LED, 0)


def test_eeprom_write_with_torque_on_is_servo_error(bus):
    bus.write(6, Reg.TORQUE_ENABLE, 1)
    try:
        with pytest.raises(ServoError) as ei:
            bus.write(6, Reg.OPERATING_MODE, 1)
        assert ei.value.id == 6
        assert ei.value.error_number == ErrorNumber.ACCESS
        assert ei.value.instruction == Instruction.WRITE
    finally:
        bus.write(6, Reg.TORQUE_ENABLE, 0)


def test_clear_reboot_factory_reset_answer(bus, emu):
    bus.clear(1)
    bus.reboot(2)
    time.sleep(0.05)
    bus.factory_reset(3)
    assert bus.ping(3).id == 3


# --- faults (emulator only) -------------------------------------------------------------------

def test_missing_servo_times_out_naming_it(bus, emu):
    bus.ping(4)  # learn the model first; otherwise the read would start with a Ping
    emu.faults.vanish(4)
    with pytest.raises(DxlTimeoutError) as ei:
        bus.read(4, Reg.PRESENT_POSITION)
    assert ei.value.ids == (4,) and ei.value.instruction == Instruction.READ
    assert ei.value.timeout_s > 0
    with pytest.raises(DxlTimeoutError) as ei:
        bus.sync_read(IDS, Reg.PRESENT_POSITION)
    assert 4 in ei.value.ids and 1 not in ei.value.ids
    with pytest.raises(DxlTimeoutError) as ei:  # one combined reply, cut short before ID 4's slice
        bus.sync_read(IDS, Reg.PRESENT_POSITION, fast=True)
    assert ei.value.first_missing == 4 and "stopped after 3 of 8 slices" in str(ei.value)
    emu.faults.restore(4)
    assert bus.read(4, Reg.ID) == 4


def test_vanished_servo_is_named_first_and_the_rest_cut_off(bus, emu):
    bus.sync_read(IDS, Reg.PRESENT_POSITION)   # learn the models (no Ping in the failing read)
    emu.faults.vanish(3)
    with pytest.raises(DxlTimeoutError) as ei:
        bus.sync_read(IDS, Reg.PRESENT_POSITION)
    err = ei.value
    assert err.ids == (3, 4, 5, 6, 7, 8)       # every ID that did not answer
    assert err.first_missing == 3 and err.cut_off
    assert str(err).startswith("servo ID 3 stopped answering")
    assert "IDs 4, 5, 6, 7, 8 queued behind it" in str(err) and "cut off" in str(err)


def test_vanished_servo_in_a_fast_read_is_named_from_the_slices_that_came(bus, emu):
    bus.sync_read(IDS, Reg.PRESENT_POSITION, fast=True)
    emu.faults.vanish(3)
    with pytest.raises(DxlTimeoutError) as ei:
        bus.sync_read(IDS, Reg.PRESENT_POSITION, fast=True)
    err = ei.value
    assert err.ids == (3, 4, 5, 6, 7, 8) and err.first_missing == 3 and err.cut_off
    assert "stopped after 2 of 8 slices" in str(err)


def test_silent_servo_in_a_single_read_is_not_a_chain(bus, emu):
    bus.ping(2)
    emu.faults.vanish(2)
    with pytest.raises(DxlTimeoutError, match=r"^no reply from servo ID 2 to READ") as ei:
        bus.read(2, Reg.PRESENT_POSITION)
    assert ei.value.first_missing == 2 and not ei.value.cut_off


def test_hardware_alert_attaches_decoded_bits(bus, emu):
    emu.faults.raise_hardware_error(2, HardwareError.OVERLOAD | HardwareError.OVERHEATING)
    with pytest.raises(ServoError) as ei:
        bus.read(2, Reg.PRESENT_POSITION)
    err = ei.value
    assert err.id == 2 and err.alert
    assert err.error_number == ErrorNumber.NONE
    assert "overload" in err.hardware_error and "overheating" in err.hardware_error
    assert bus.hardware_error(2) == HardwareError.OVERLOAD | HardwareError.OVERHEATING
    bus.reboot(2)  # clears the latch; the reboot status itself carries the alert, tolerated
    assert _eventually(lambda: bus.hardware_error(2) == 0)
    assert bus.read(2, Reg.ID) == 2


def test_corrupt_replies_raise_corrupt_packet(target, emu):
    """A flipped bit may hit the CRC-covered body (CorruptPacketError) or the header, ID or
    LENGTH (then nothing valid arrives: DxlTimeoutError); never anything else, never a hang."""
    with Bus(target.url, target.baud, timeout_margin_s=0.05, default_model="xh430-w210") as b:
        emu.faults.corrupt_rate = 1.0
        kinds = []
        for _ in range(16):
            with pytest.raises((CorruptPacketError, DxlTimeoutError)) as ei:
                b.read(1, Reg.PRESENT_POSITION)
            kinds.append(type(ei.value))
        emu.faults.corrupt_rate = 0.0
        assert any(issubclass(k, CorruptPacketError) for k in kinds)
        assert b.corrupt_frames >= 1
        assert b.read(1, Reg.ID) == 1


def test_bounded_retries_recover_dropped_replies(target, emu):
    emu.faults.drop_rate = 0.5
    with Bus(target.url, target.baud, timeout_margin_s=0.05, retries=12) as b:
        for _ in range(5):
            assert b.read(1, Reg.ID) == 1
    emu.faults.drop_rate = 1.0
    with Bus(target.url, target.baud, timeout_margin_s=0.02, retries=2) as b:
        with pytest.raises(DxlTimeoutError):
            b.read(1, Reg.ID)
    emu.faults.drop_rate = 0.0


# --- wire oddities (scripted responder) ---------------------------------------------------------

def test_reply_from_wrong_id_is_ignored_and_counted(fake):
    fake.wrong_id[1] = 9
    with Bus(fake.port, timeout_margin_s=0.1, default_model="xh430-w210") as b:
        with pytest.raises(DxlTimeoutError):
            b.read(1, Reg.ID)
        assert b.stray_replies == 1


def test_garbage_before_reply_is_skipped(fake):
    fake.garbage_before = b"\x00\xff\xff\x17noise\xff\xff\xfd\x00\x01\xff"
    with Bus(fake.port, timeout_margin_s=0.2, default_model="xh430-w210") as b:
        assert b.read(3, Reg.ID) == 3


def test_bad_crc_reply_is_corrupt_then_retry_succeeds(fake):
    with Bus(fake.port, timeout_margin_s=0.1, default_model="xh430-w210") as b:
        fake.corrupt_next = 1
        with pytest.raises(CorruptPacketError, match="CRC"):
            b.read(1, Reg.ID)
    with Bus(fake.port, timeout_margin_s=0.1, default_model="xh430-w210", retries=1) as b:
        fake.corrupt_next = 1
        assert b.read(1, Reg.ID) == 1


def test_status_error_fields(fake):
    fake.error_byte[5] = ErrorNumber.DATA_RANGE
    with Bus(fake.port, timeout_margin_s=0.2, default_model="xh430-w210") as b:
        with pytest.raises(ServoError) as ei:
            b.write(5, Reg.GOAL_POSITION, 100)
    assert (ei.value.id, ei.value.error_number, ei.value.alert) == (5, ErrorNumber.DATA_RANGE, False)
    assert "range" in str(ei.value)


def test_lock_serialises_threads(bus):
    import threading

    errors = []

    def worker(i):
        try:
            for _ in range(10):
                assert bus.read(i, Reg.ID) == i
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(i,)) for i in (1, 2, 3, 4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors
