"""Transport: timeout arithmetic, latency-timer detection, deadline reads (pure and loop://)."""
from __future__ import annotations

import time
import warnings

import pytest

from swerve.driver import packets as pk
from swerve.driver.errors import TransportError
from swerve.driver.transport import (Transport, latency_fix_command, latency_timer_ms, open_port,
                              packet_timeout_s)


def test_packet_timeout_components():
    # 100 bytes at 1 Mbps = 1 ms; 500 us return delay; 2 x 1 ms latency; 2 ms margin
    assert packet_timeout_s(1_000_000, 100, 500, 1, 0.002) == pytest.approx(0.0055)
    assert packet_timeout_s(57_600, 0, 0, 0, 0) == 0
    assert packet_timeout_s(57_600, 14, 0, 0, 0) == pytest.approx(140 / 57_600)
    # the 16 ms FTDI default dominates at 1 Mbps
    assert packet_timeout_s(1_000_000, 30, 0, 16, 0) > 0.032


@pytest.mark.parametrize("kw", [dict(baud=0), dict(nbytes=-1), dict(return_delay_us=-1),
                                dict(latency_timer_ms=-1)])
def test_packet_timeout_rejects_bad_input(kw):
    args = dict(baud=1_000_000, nbytes=10, return_delay_us=0, latency_timer_ms=0) | kw
    with pytest.raises(ValueError):
        packet_timeout_s(**args)


def _fake_sysfs(tmp_path, value):
    dev = tmp_path / "dev" / "ttyUSB3"
    dev.parent.mkdir()
    dev.write_text("")
    sysfs = tmp_path / "sys"
    (sysfs / "ttyUSB3").mkdir(parents=True)
    (sysfs / "ttyUSB3" / "latency_timer").write_text(f"{value}\n")
    return str(dev), str(sysfs)


def test_latency_timer_warns_with_fix(tmp_path):
    port, sysfs = _fake_sysfs(tmp_path, 16)
    with pytest.warns(RuntimeWarning, match="echo 1 | sudo tee .*/ttyUSB3/latency_timer"):
        assert latency_timer_ms(port, sysfs_root=sysfs) == 16


def test_latency_timer_quiet_at_1ms_and_symlink(tmp_path):
    port, sysfs = _fake_sysfs(tmp_path, 1)
    link = tmp_path / "by-id"
    link.symlink_to(port)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert latency_timer_ms(str(link), sysfs_root=sysfs) == 1


def test_latency_timer_not_usb():
    assert latency_timer_ms("loop://") is None
    assert latency_timer_ms("/dev/pts/0") is None
    assert latency_fix_command() == "echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer"


def test_open_missing_port_names_it():
    with pytest.raises(TransportError, match="/dev/does-not-exist"):
        open_port("/dev/does-not-exist", 1_000_000)


def test_loop_echo_returns_packet():
    t = Transport("loop://", 1_000_000)
    frame = pk.ping(1).encode()
    t.write(frame)
    got = t.read_packets(time.monotonic() + 1.0)
    assert got == [pk.ping(1)]
    t.close()


def test_garbage_truncated_and_bad_crc_are_skipped():
    t = Transport("loop://", 1_000_000)
    good = pk.StatusPacket(3, 0, b"\x01\x02").encode()
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    truncated = good[:8]
    t.write(b"\x00\xff\x13garbage" + truncated + bytes(bad_crc) + good)
    got = t.read_packets(time.monotonic() + 1.0)
    assert got == [pk.StatusPacket(3, 0, b"\x01\x02")]
    assert t.parser.take_errors()  # the bad frames were seen and reported
    t.close()


def test_read_blocks_until_deadline_without_spinning():
    t = Transport("loop://", 1_000_000)
    cpu0, wall0 = time.thread_time(), time.monotonic()
    assert t.read_packets(wall0 + 0.3) == []
    waited, cpu = time.monotonic() - wall0, time.thread_time() - cpu0
    assert waited >= 0.3
    assert cpu < 0.15  # a busy-wait would burn ~0.3 s of CPU
    t.close()


def test_pty_read_blocks_without_spinning(fake):
    t = Transport(fake.port, 1_000_000)
    fake.silent.update(range(1, 9))
    t.write(pk.ping(1).encode())
    cpu0, wall0 = time.thread_time(), time.monotonic()
    assert t.read_packets(wall0 + 0.3) == []
    assert time.monotonic() - wall0 >= 0.3
    assert time.thread_time() - cpu0 < 0.15
    t.close()


def test_closed_port_raises_transport_error():
    t = Transport("loop://", 1_000_000)
    t.close()
    with pytest.raises(TransportError):
        t.write(b"\x00")


def test_bus_ignores_its_own_echo():
    """On loop:// the only thing that comes back is our instruction: not a reply."""
    from swerve.driver.bus import Bus
    from swerve.driver.errors import DxlTimeoutError

    with Bus("loop://", default_model="xh430-w210", timeout_margin_s=0.05) as bus:
        with pytest.raises(DxlTimeoutError) as ei:
            bus.read(1, "present_position")
    assert ei.value.ids == (1,)
