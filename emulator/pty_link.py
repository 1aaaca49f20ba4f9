"""The pseudo-terminal the emulated bus lives on.

The client (SDK, driver, any serial tool) opens the slave path like a U2D2 port; the emulator
reads and writes the master. The slave fd stays open here, so a client closing and reopening
the port never makes the master report EIO. The master is non-blocking for writes: a client
that never reads loses bytes (like an overflowing USB buffer) instead of stalling the emulator.

The master runs in packet mode (``TIOCPKT``, Linux ``tty_ioctl(4)``): every read starts with a
control byte, ``TIOCPKT_DATA`` (0) before data, or status bits alone. ``TIOCPKT_FLUSHWRITE``
says the client called ``tcflush(fd, TCOFLUSH)``, which on a pty discards the bytes it wrote
that are still in the kernel's pty buffer, not yet passed to the master (a U2D2 has already
sent them). The kernel does not say how
many bytes went; :class:`PtyLink` reports each such flush to ``on_output_flush``.
"""
from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import struct
import sys
import termios
import threading
import tty
from pathlib import Path
from typing import Callable

#: Linux ``TCGETS2`` (struct termios2, 44 bytes: c_ispeed/c_ospeed at offsets 36/40).
_TCGETS2 = 0x802C542A
_SPEED_CONSTANTS = {value: int(name[1:]) for name, value in vars(termios).items()
                    if name.startswith("B") and name[1:].isdigit()}


#: Linux ``prctl`` option that sets the calling thread's timer slack (``linux/prctl.h``).
_PR_SET_TIMERSLACK = 29
#: Timer slack asked for by :func:`precise_timers`, ns (the Linux default is 50 000).
TIMER_SLACK_NS = 1000
class _ThreadFlag(threading.local):
    """A per-thread flag, False in every thread until set."""

    done = False


_precise = _ThreadFlag()
#: Packet-mode control byte before data, and the status bit of a client's output flush.
_PKT_DATA = termios.TIOCPKT_DATA
_PKT_FLUSHWRITE = termios.TIOCPKT_FLUSHWRITE


def precise_timers() -> None:
    """Give the calling thread a 1 us timer slack (Linux ``PR_SET_TIMERSLACK``; once per thread).

    Linux lets a timed sleep end up to the thread's timer slack late, 50 us by default, so a
    reply paced with ``time.sleep`` would reach the client that much after its wire time.
    Elsewhere, or if the call fails, the thread keeps its slack.
    """
    if _precise.done:
        return
    _precise.done = True
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, TIMER_SLACK_NS, 0, 0, 0)
    except (OSError, AttributeError):
        pass


class PtyLink:
    """A raw pty pair; ``path`` is the slave device the client opens.

    ``link`` optionally names a symlink created to the slave (removed on :meth:`close`).
    ``on_output_flush`` is called (in the reading thread) each time a read finds that the client
    flushed its output queue; :attr:`output_flushes` counts those flushes.
    """

    def __init__(self, baud_bps: int = 1_000_000, link: str | os.PathLike | None = None,
                 on_output_flush: Callable[[], None] | None = None):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self._set_speed(baud_bps)
        flags = fcntl.fcntl(self.master, fcntl.F_GETFL)
        fcntl.fcntl(self.master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        fcntl.ioctl(self.master, termios.TIOCPKT, struct.pack("i", 1))
        self.on_output_flush = on_output_flush
        #: Client output flushes seen (``TIOCPKT_FLUSHWRITE`` status reads).
        self.output_flushes = 0
        self.link: Path | None = None
        if link is not None:
            try:                        # fails if anything exists there: nothing is replaced
                Path(link).symlink_to(self.path)
            except OSError as exc:
                self.close()
                why = "it exists (remove it or choose another path)" if isinstance(exc, FileExistsError) \
                    else exc.strerror
                raise FileExistsError(exc.errno, f"cannot create the link {link}: {why}") from None
            self.link = Path(link)

    def _set_speed(self, bps: int) -> None:
        const = {v: k for k, v in _SPEED_CONSTANTS.items()}.get(int(bps))
        if const is None:
            return
        attrs = termios.tcgetattr(self.slave)
        attrs[4] = attrs[5] = const
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)

    def speed_bps(self) -> int:
        """The line speed the client last set (0 if unknown or B0)."""
        buf = bytearray(44)
        try:
            fcntl.ioctl(self.master, _TCGETS2, buf)
            speed = struct.unpack_from("<I", buf, 40)[0]
            if speed:
                return speed
        except OSError:
            pass
        try:
            return _SPEED_CONSTANTS.get(termios.tcgetattr(self.master)[5], 0)
        except termios.error:
            return 0

    def read(self, n: int = 4096) -> bytes:
        """Up to ``n`` bytes the client sent (b"" if none are waiting, or if this read found a
        status change instead: an output flush is counted and reported, see the class)."""
        try:
            data = os.read(self.master, n + 1)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return b""
            raise
        if not data:
            return b""
        if data[0] == _PKT_DATA:
            return data[1:]
        if data[0] & _PKT_FLUSHWRITE:
            self.output_flushes += 1
            if self.on_output_flush is not None:
                self.on_output_flush()
        return b""

    def write(self, data: bytes) -> int:
        """Send ``data`` to the client; returns bytes accepted (the rest is lost if the buffer is full)."""
        sent = 0
        while sent < len(data):
            try:
                n = os.write(self.master, data[sent:])
            except BlockingIOError:
                break
            if n <= 0:
                break
            sent += n
        return sent

    def close(self) -> None:
        """Close both ends and remove the symlink (only if it is still the one made here)."""
        if self.link is not None and self.link.is_symlink() and os.readlink(self.link) == self.path:
            try:
                self.link.unlink()
            except OSError:
                pass
            self.link = None
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self.master = self.slave = -1
