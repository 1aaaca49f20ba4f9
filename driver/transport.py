"""Serial transport: open a port by URL, write frames, block for packets until a deadline.

Any URL pyserial knows works: ``/dev/ttyUSB0`` (U2D2), a pty path (the emulator) or
``loop://`` (echo). Reads block in ``select()`` (or pyserial's own blocking read for
ports without a file descriptor) with the time left to a :func:`time.monotonic`
deadline; nothing spins. On a plain serial device the transport talks to the file
descriptor directly: one ``write`` per request, and one ``read`` of everything available
per ``select`` wakeup.

A reply that arrives in pieces (a Sync Read's chain of statuses, several USB transfers) wakes
``select`` once per piece, and each piece is decoded while the rest is still on the wire.
Waiting for the whole reply instead, with termios VMIN set to its size (Linux n_tty reports a
tty readable to poll only once VMIN bytes are queued when VTIME is 0: ``input_available_p``
in ``drivers/tty/n_tty.c``; with VMIN above 64 each ``read`` then returns at most 64 bytes,
``iterate_tty_read`` in ``drivers/tty/tty_io.c``), halves the wakeups of an 8-servo Sync Read
but moves that decoding behind the last byte: 3-4 % fewer round trips per second against the
emulator with 1 Mbps wire timing (``bench/bench_emulator.py``), so the transport keeps
pyserial's VMIN.

A device or pty path is opened with pyserial's ``exclusive=True``: an advisory
``flock(LOCK_EX | LOCK_NB)`` on the device, so a second swerve program on the same bus is
refused with :class:`PortInUseError` instead of interleaving its writes with the first one's.
(The lock is advisory: a program that does not ask for it, e.g. the Dynamixel SDK's
``PortHandler``, is not kept out.)

Every OS-level failure of the port (unplugged adapter, ``termios.error``, EIO, a closed
or invalid descriptor, end of file) is raised as a :class:`TransportError` naming the port.

Reply timeouts come from :func:`packet_timeout_s`: bytes on the wire at the baud rate,
the servos' Return Delay Time, and the USB-serial latency timer, which on Linux is a
per-device sysfs file (FTDI default 16 ms; set it to 1 ms, see :func:`latency_timer_ms`).
"""
from __future__ import annotations

import errno
import fcntl
import logging
import os
import re
import select
import struct
import termios
import time
import warnings
from typing import Callable

import serial

from swerve.driver.errors import PortInUseError, TransportError
from swerve.driver.parser import PacketParser

log = logging.getLogger(__name__)


#: Bits on the wire per byte: start + 8 data + stop.
BITS_PER_BYTE = 10

#: Fixed slack added to every reply timeout (OS scheduling, servo processing), s.
DEFAULT_MARGIN_S = 0.002

#: What a dead or closed port raises below us: termios.error is not an OSError, and
#: select()/fileno() on a closed descriptor raise ValueError.
_PORT_ERRORS = (OSError, termios.error, serial.SerialException, TypeError, ValueError)
#: Largest read per wakeup, bytes (several whole replies).
_READ_CHUNK = 4096

_SYSFS_USB_SERIAL = "/sys/bus/usb-serial/devices"
_TTYUSB = re.compile(r"^ttyUSB\d+$")


def packet_timeout_s(baud: int, nbytes: int, return_delay_us: float = 500.0,
                     latency_timer_ms: float = 0.0, margin_s: float = DEFAULT_MARGIN_S) -> float:
    """Time to wait for a reply, s.

    ``nbytes`` bytes at ``baud`` (10 bits each), plus the servo's Return Delay Time
    (``return_delay_us``), plus twice the USB latency timer (the request may wait one
    period to leave the adapter and the reply one period to come back), plus ``margin_s``.
    """
    if baud <= 0:
        raise ValueError(f"baud must be positive, got {baud}")
    if nbytes < 0 or return_delay_us < 0 or latency_timer_ms < 0 or margin_s < 0:
        raise ValueError("nbytes, return_delay_us, latency_timer_ms and margin_s must be >= 0")
    return (nbytes * BITS_PER_BYTE / baud + return_delay_us * 1e-6
            + 2.0 * latency_timer_ms * 1e-3 + margin_s)


def latency_fix_command(device: str = "ttyUSB0") -> str:
    """The one-line shell fix that sets a device's latency timer to 1 ms."""
    return f"echo 1 | sudo tee {_SYSFS_USB_SERIAL}/{device}/latency_timer"


def latency_timer_ms(port: str, *, warn: bool = True,
                     sysfs_root: str = _SYSFS_USB_SERIAL) -> int | None:
    """The USB-serial latency timer of ``port`` in ms, or ``None`` if it is not a ttyUSB.

    Reads ``/sys/bus/usb-serial/devices/ttyUSBn/latency_timer`` (symlinks such as
    ``/dev/serial/by-id/...`` are resolved). When ``warn`` and the value is above 1 ms,
    issues a :class:`RuntimeWarning` carrying the one-line fix.
    """
    if "://" in port:
        return None
    dev = os.path.basename(os.path.realpath(port))
    if not _TTYUSB.match(dev):
        return None
    path = os.path.join(sysfs_root, dev, "latency_timer")
    try:
        with open(path) as fh:
            value = int(fh.read().strip())
    except (OSError, ValueError):
        return None
    if warn and value > 1:
        msg = (f"{port}: USB latency timer is {value} ms (every reply waits up to that long); "
               f"set it to 1 ms: {latency_fix_command(dev)}")
        log.warning(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
    return value


def open_port(url: str, baud: int, timeout_s: float = 0.1) -> serial.SerialBase:
    """Open ``url`` with :func:`serial.serial_for_url` at ``baud``, 8N1, blocking reads.

    ``timeout_s`` bounds a single blocking read; :class:`Transport` sets its own
    deadlines. On a ttyUSB, low-latency mode is requested (ignored where unsupported).
    A device or pty path is locked for this process (see the module notes). Raises
    :class:`PortInUseError` when another program holds the port, :class:`TransportError`
    naming the port on any other failure.
    """
    lock = {} if "://" in url else {"exclusive": True}
    try:
        port = serial.serial_for_url(url, baudrate=int(baud), timeout=timeout_s,
                                     write_timeout=max(1.0, timeout_s), **lock)
    except (serial.SerialException, OSError, ValueError) as exc:
        if lock and getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK):
            raise PortInUseError(f"serial port {url} is in use by another program (it holds the port's "
                                 f"lock); stop that program first", port=url) from None
        raise TransportError(f"cannot open serial port {url!r} at {baud} bps: {exc}") from None
    if "://" not in url and _TTYUSB.match(os.path.basename(os.path.realpath(url))):
        try:
            port.set_low_latency_mode(True)
        except (AttributeError, OSError, ValueError, serial.SerialException) as exc:
            log.debug("%s: low-latency mode not available: %s", url, exc)
    return port


class Transport:
    """One open port plus an incremental :class:`PacketParser`.

    ``write(frame)`` discards stale input and sends; ``read_packets(deadline)`` blocks
    until at least one complete packet has arrived or ``deadline`` (a
    :func:`time.monotonic` value) passes. Not thread-safe: :class:`driver.bus.Bus`
    holds the lock. Every failure of the port is a :class:`TransportError`.
    """

    def __init__(self, url: str, baud: int, *, port: serial.SerialBase | None = None):
        self.url = url
        self.baud = int(baud)
        self._port = port if port is not None else open_port(url, baud)
        self.parser = PacketParser()
        # a plain POSIX serial port (U2D2, pty) is driven through its descriptor, which
        # pyserial opens non-blocking; wrappers (spy://, loop://) keep their own read/write
        self._fd: int | None = None
        if type(self._port) is serial.Serial:
            try:
                self._fd = self._port.fileno()
            except (AttributeError, NotImplementedError, OSError, serial.SerialException):
                self._fd = None
        #: Bytes handed to the port since it was opened (a lockstep barrier counts on it).
        self.bytes_written = 0
        #: Bytes that came in since the port was opened: read, or discarded unread before a write.
        self.bytes_received = 0
        #: Called after each :meth:`write` has sent all its bytes (e.g. a lockstep clock
        #: announcing them to its emulator while the reply is on its way); None: nothing.
        self.after_write: Callable[[], None] | None = None
        #: Latency timer of the adapter in ms (0 when not a ttyUSB).
        self.latency_timer_ms = latency_timer_ms(url) or 0 if "://" not in url else 0

    @property
    def is_open(self) -> bool:
        return bool(self._port is not None and self._port.is_open)

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._fd = None
        if self._port is not None and self._port.is_open:
            try:
                self._port.close()
            except _PORT_ERRORS:
                pass

    def _failed(self, what: str, exc: BaseException | str) -> TransportError:
        if isinstance(exc, termios.error) and len(exc.args) == 2:  # args (errno, text)
            exc = f"[Errno {exc.args[0]}] {exc.args[1]}"
        return TransportError(f"serial port {self.url}: {what} failed: {exc} "
                              f"(adapter unplugged or port closed?)")

    def _check_open(self, what: str) -> None:
        if not self.is_open:
            raise self._failed(what, "the port is closed")

    def write(self, data: bytes) -> None:
        """Drop unread input and buffered partial frames, then send ``data``."""
        self._check_open("write")
        self.parser.reset()
        fd = self._fd
        try:
            if fd is None:
                stale = self._port.in_waiting
                if stale:
                    self.bytes_received += stale
                    self._port.reset_input_buffer()
                n = self._port.write(data)
                if n is not None and n != len(data):
                    raise self._failed("write", f"only {n} of {len(data)} bytes sent")
                self.bytes_written += len(data)
            else:
                self._write_fd(fd, data)
        except TransportError:
            raise
        except _PORT_ERRORS as exc:
            raise self._failed("write", exc) from None
        if self.after_write is not None:
            self.after_write()

    def _write_fd(self, fd: int, data: bytes) -> None:
        """Send ``data`` on the non-blocking descriptor, waiting (bounded) while its queue is full."""
        stale = struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
        if stale:       # only then: a flush wakes a pty master in packet mode
            self.bytes_received += stale
            termios.tcflush(fd, termios.TCIFLUSH)
        view, deadline = memoryview(data), None
        while view:
            try:
                n = os.write(fd, view)
                self.bytes_written += n
                view = view[n:]
            except BlockingIOError:  # output queue full: wait until it drains
                deadline = deadline or time.monotonic() + max(1.0, len(data) * 20 / self.baud)
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not select.select([], [fd], [], remaining)[1]:
                    raise self._failed("write", f"{len(view)} of {len(data)} bytes not sent "
                                                f"in time") from None

    def _read_chunk(self, remaining_s: float) -> bytes:
        """Whatever arrives within ``remaining_s`` (``b""`` if nothing); raises TransportError."""
        self._check_open("read")
        fd = self._fd
        try:
            if fd is None:
                port = self._port
                port.timeout = remaining_s
                data = port.read(max(1, port.in_waiting))
                self.bytes_received += len(data)
                return data
            if not select.select([fd], [], [], remaining_s)[0]:
                return b""
            try:
                data = os.read(fd, _READ_CHUNK)
            except BlockingIOError:
                return b""
        except _PORT_ERRORS as exc:
            raise self._failed("read", exc) from None
        if not data:  # readable but end of file: the device went away
            raise self._failed("read", "end of file (device disconnected)")
        self.bytes_received += len(data)
        return data

    def drain_quiet(self, quiet_s: float, max_s: float) -> int:
        """Discard input until the line has been silent for ``quiet_s`` (at most ``max_s``).

        After a timeout a late reply may still be on its way; draining it keeps it from being
        taken as the answer to the next request. Returns the number of bytes discarded.
        """
        dropped = 0
        end = time.monotonic() + max_s
        while True:
            remaining = end - time.monotonic()
            if remaining <= 0:
                break
            chunk = self._read_chunk(min(quiet_s, remaining))
            if not chunk:
                break
            dropped += len(chunk)
        self.parser.reset()
        return dropped

    def read_packets(self, deadline: float) -> list:
        """Packets completed by bytes arriving before ``deadline`` (monotonic s).

        Returns as soon as at least one packet is complete; returns ``[]`` at the
        deadline (after giving up on a dangling partial frame).
        """
        parser = self.parser
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return parser.flush() if parser.pending else []
            chunk = self._read_chunk(remaining)
            if chunk:
                packets = parser.feed(chunk)
                if packets:
                    return packets
