"""The driver against a dead port and a hostile device; the emulator against header bombs.

Every failure must come out as a typed :class:`DxlError` (a :class:`TransportError`
naming the port for OS-level failures) within a bound set by the configured deadline.
Time bounds here are generous multiples of that deadline: the verdict is "answered" or
"raised the typed error", never a tight timing.
"""
from __future__ import annotations

import fcntl
import logging
import os
import pty
import re
import select
import termios
import threading
import time
import tty

import pytest
import serial
from hypothesis import HealthCheck, given, settings, strategies as st

from swerve.driver import packets as P
from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import DxlError, TransportError
from swerve.driver.packets import StatusPacket
from swerve.driver.parser import PacketParser
from swerve.driver.robot_config import load_robot_config
from swerve.driver.transport import Transport
from swerve.driver.wheelset import WheelSet

MIB = 1 << 20
BOMB_HUGE = b"\xff\xff\xfd\x00\x01\xa0\x0f"     # LENGTH 4000: beyond any servo packet
BOMB_LEGAL = b"\xff\xff\xfd\x00\x01\xf0\x03"    # LENGTH 1008: legal, exposed by the next header
MODEL = "xh430-w210"


class RawPty:
    """A pty pair: ``port`` is the path a client opens, ``master`` the device side."""

    def __init__(self):
        self.master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)

    def unplug(self) -> None:
        """Close the device side, as when the USB adapter is pulled."""
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self.master = self._slave = -1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.unplug()


# --- a port that dies ---------------------------------------------------------------------------

def test_unplugged_pty_raises_transport_error_naming_the_port():
    with RawPty() as dev:
        t = Transport(dev.port, 1_000_000)
        t.write(P.ping(1).encode())
        assert os.read(dev.master, 64) == P.ping(1).encode()
        dev.unplug()
        # tcflush raises termios.error (not an OSError) on a dead line
        with pytest.raises(TransportError, match=re.escape(dev.port) + r".*\[Errno 5\]"):
            t.write(P.ping(1).encode())
        with pytest.raises(TransportError, match=re.escape(dev.port)):
            t.read_packets(time.monotonic() + 1.0)
        with pytest.raises(TransportError, match=re.escape(dev.port)):
            t.drain_quiet(0.01, 0.1)
        t.close()
        with pytest.raises(TransportError, match="closed"):
            t.write(P.ping(1).encode())


@pytest.mark.parametrize("where,exc", [
    ("tcflush", termios.error(5, "Input/output error")),
    ("ioctl", OSError(5, "Input/output error")),
    ("select", ValueError("file descriptor cannot be a negative integer (-1)")),
    ("select", OSError(9, "Bad file descriptor")),
], ids=["termios_error", "ioctl_error", "select_negative_fd", "select_ebadf"])
def test_every_os_failure_is_a_transport_error(monkeypatch, where, exc):
    with RawPty() as dev:
        t = Transport(dev.port, 1_000_000)
        module = {"tcflush": termios, "ioctl": fcntl}.get(where, select)
        os.write(dev.master, b"stale")              # unread input: the write flushes it first
        deadline = time.monotonic() + 5
        while not select.select([t._fd], [], [], 0)[0] and time.monotonic() < deadline:
            time.sleep(0.001)                       # the pty hands the bytes over asynchronously

        def fail(*_args):
            raise exc

        monkeypatch.setattr(module, where, fail)
        with pytest.raises(TransportError, match=re.escape(dev.port)):
            t.write(P.ping(1).encode())
            t.read_packets(time.monotonic() + 0.5)
        monkeypatch.undo()
        t.close()


def test_bus_on_unplugged_port_raises_transport_error():
    with RawPty() as dev, Bus(dev.port, 1_000_000, default_model=MODEL) as bus:
        dev.unplug()
        with pytest.raises(TransportError, match=re.escape(dev.port)):
            bus.sync_read([1, 2], Reg.PRESENT_POSITION)


def test_wheelset_shutdown_survives_an_unplugged_port(caplog):
    cfg = load_robot_config()
    with RawPty() as dev, Bus(dev.port, 1_000_000, default_model=MODEL) as bus:
        caplog.set_level(logging.WARNING)
        with pytest.raises(TransportError) as ei:
            with WheelSet(bus, cfg) as wheels:
                dev.unplug()
                wheels.read_state()
        msg = str(ei.value)
        assert dev.port in msg                       # the original failure comes first
        assert "left to their Bus Watchdog" in msg and f"{cfg.bus_watchdog_s:g} s" in msg
        assert "left to their Bus Watchdog" in caplog.text


def test_wheelset_clean_exit_on_a_dead_port_raises_the_watchdog_note():
    cfg = load_robot_config()
    with RawPty() as dev, Bus(dev.port, 1_000_000, default_model=MODEL) as bus:
        with pytest.raises(TransportError, match="could not stop the servos .*Bus Watchdog"):
            with WheelSet(bus, cfg):
                dev.unplug()


# --- a hostile device ---------------------------------------------------------------------------

class HostileDevice(RawPty):
    """Answers every instruction it hears with ``script``: ``(bytes, pause_s)`` pieces."""

    def __init__(self):
        super().__init__()
        self.script: list[tuple[bytes, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        parser = PacketParser()
        while not self._stop.is_set():
            try:
                if not select.select([self.master], [], [], 0.05)[0]:
                    continue
                data = os.read(self.master, 4096)
                for _ in parser.feed(data):
                    for piece, pause_s in list(self.script):
                        if pause_s and self._stop.wait(pause_s):
                            return
                        os.write(self.master, piece)
            except (OSError, ValueError):
                return

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(2)
        super().__exit__(*exc)


def _status(id_, n):
    return StatusPacket(id_, 0, bytes(range(n))).encode()


_pieces = st.one_of(
    st.binary(min_size=1, max_size=60),                                         # garbage
    st.sampled_from([BOMB_HUGE, BOMB_LEGAL, b"\xff\xff\xfd\x00\x01\xff\xff",     # huge lengths
                     b"\xff\xff\xfd\x00\xfe\x20\x00\x55\x00"]),                  # unrequested fast reply
    st.builds(_status, st.integers(0, 252), st.integers(0, 8)),                 # wrong IDs / sizes
    st.builds(lambda i, k: _status(i, 4)[:k], st.integers(1, 2), st.integers(1, 14)),  # truncated
    st.builds(_status, st.integers(1, 2), st.just(4)),                           # a right answer
)
_script = st.lists(st.tuples(_pieces, st.sampled_from([0.0, 0.0, 0.001, 0.004])), max_size=12)


@pytest.fixture(scope="module")
def hostile():
    with HostileDevice() as dev, Bus(dev.port, 1_000_000, default_model=MODEL,
                                     timeout_margin_s=0.02) as bus:
        yield dev, bus


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(script=_script, op=st.sampled_from(["ping", "read", "sync_read", "fast_sync_read"]))
def test_hostile_device_gives_a_typed_error_in_bounded_time(hostile, script, op):
    dev, bus = hostile
    dev.script = script
    call = {
        "ping": lambda: bus.ping(1),
        "read": lambda: bus.read(1, Reg.PRESENT_POSITION),
        "sync_read": lambda: bus.sync_read([1, 2], Reg.PRESENT_POSITION),
        "fast_sync_read": lambda: bus.sync_read([1, 2], Reg.PRESENT_POSITION, fast=True),
    }[op]
    # the longest deadline of these requests; a failed exchange drains at most 10x that first
    deadline_s = bus.timeout_s(64, 2)
    t0 = time.monotonic()
    try:
        call()
    except DxlError:
        pass
    elapsed = time.monotonic() - t0
    assert elapsed < 11 * deadline_s + 2.0


# --- the emulator under header bombs ------------------------------------------------------------

def test_emulator_answers_ping_after_1mib_of_header_bombs(target, emu):
    bombs = (BOMB_HUGE + BOMB_LEGAL) * (MIB // (len(BOMB_HUGE) + len(BOMB_LEGAL)))
    with serial.Serial(emu.port, 1_000_000, timeout=0, write_timeout=300) as raw:
        raw.write(bombs)        # returns once the emulator has taken nearly all of it
    # a generous deadline: the verdict is that the ping is answered at all
    with Bus(emu.port, 1_000_000, timeout_margin_s=30.0) as bus:
        assert bus.ping(1).id == 1
    assert emu.stats.bad_frames >= len(bombs) // 14
