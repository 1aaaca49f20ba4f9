"""The lockstep control channel: a Unix socket beside the pty through which a client owns time.

The bytes of every request and reply still travel through the pty; this channel only moves
robot time (:class:`swerve.emulator.clock.LockstepPhysicsClock`) and reads the true state. It is served
by the emulator's bus thread, between requests, so time, bus and physics change in one order.

Protocol (ASCII lines, one reply line per request; times in s as Python ``repr`` floats)::

    advance <t_s> <tx_bytes>   ->  at <now_s> <asked_s>       robot time moved to max(now, t_s)
                                                              from asked_s (after the bytes); the
                                                              physics runs after this answer, before
                                                              a pty byte or pose/fault is served
    now <tx_bytes>             ->  at <now_s>
    pose <tx_bytes>            ->  pose <now_s> <x_m> <y_m> <theta_rad> <physics_t_s>
    sent <tx_bytes>            ->  sent <now_s> <bytes>         bytes written to the pty since this
                                                              client connected (replies included)
    fault <tx_bytes> <what> <args>  ->  ok                   vanish ID | restore ID | hwerror ID BITS
    stats                      ->  stats <key> <int> ...      the bus counters (replies_dropped, ...)
    info                       ->  info rate_hz <hz> reply_latency_s <s> baud <bps> adapter_latency_ms <ms> body <0|1>
    (anything else)            ->  error <text>

Limits: at most :data:`MAX_CLIENTS` connections; a request line is ASCII and at most
:data:`MAX_LINE_BYTES` long; ``advance`` moves robot
time by at most :data:`MAX_ADVANCE_S`; ``tx_bytes`` is at most :data:`MAX_TX_BYTES`. A request
outside them is answered with ``error``; a client whose line overruns the cap, or that does not
read its replies (its socket buffer fills), is disconnected. The bus is never stopped by a client.

``BITS`` of ``hwerror`` are ``+``-separated names (``overload+overheating``) or an integer. A
fault sent this way takes effect at a known point of robot time (after the announced bytes).

``tx_bytes`` is the number of bytes the client wrote to the pty since its previous request on
this connection (or since it connected). Before answering, the emulator reads the pty until it
has received that many more bytes and serves the instructions they complete: the Linux pty
hands bytes to the other side asynchronously, and this barrier makes the order of "bytes
written, then time advanced" deterministic. Connect before writing to the pty.
"""
from __future__ import annotations

import errno
import logging
import math
import os
import socket
import stat
import tempfile
from pathlib import Path
from typing import Protocol

from swerve.core.errors import SwerveError

log = logging.getLogger(__name__)

#: Longest the bus thread waits by default for bytes a barrier announced before answering with an
#: error, s (:class:`ControlServer`'s ``barrier_timeout_s``).
BARRIER_TIMEOUT_S = 10.0
#: Longest request line, bytes (the longest valid one is under 100); a longer one drops the client.
MAX_LINE_BYTES = 1024
#: Most control connections open at once; a further one is told so and closed.
MAX_CLIENTS = 16
#: Bytes read from a client per wakeup of the bus thread.
RECV_CHUNK = 4096
#: Largest robot time one ``advance`` may move, s: the bus thread runs the physics over it
#: before it serves anything else (a minute of physics at 1 kHz is 60 000 steps).
MAX_ADVANCE_S = 60.0
#: Largest ``tx_bytes`` a request may announce (far above a second of 4.5 Mbps wire).
MAX_TX_BYTES = 1 << 20


class ControlledBus(Protocol):
    """What the channel needs from :class:`swerve.emulator.server.Emulator`."""

    rx_bytes: int
    tx_bytes: int
    world: object | None        # the robot body (None: a bus without one, so no pose)

    def receive_until(self, rx_bytes: int, timeout_s: float) -> bool:
        """Serve the pty until ``rx_bytes`` bytes have arrived in all; False on timeout."""

    def move_to(self, t_s: float) -> float:
        """Move robot time to ``t_s`` (never back); the new robot time. The physics follows
        before the bus serves anything else (or in :meth:`settle`)."""

    def settle(self) -> None:
        """Run the physics up to robot time (before the true state is read or a fault applied)."""

    def robot_time_s(self) -> float:
        """Robot time now."""

    def control_info(self) -> str:
        """The ``info`` reply's fields."""

    def true_state(self) -> tuple[float, tuple[float, float, float]]:
        """``(physics_time_s, pose)``."""

    def inject_fault(self, what: str, args: list[str]) -> None:
        """Apply a fault now (``vanish``, ``restore``, ``hwerror``); ValueError if malformed."""

    def counters(self) -> dict[str, int]:
        """The bus counters."""


class _Connection:
    def __init__(self, sock: socket.socket, rx_base: int, tx_base: int):
        self.sock = sock
        self.buffer = bytearray()     # bytes after the last complete line (at most MAX_LINE_BYTES)
        self.rx_base = rx_base        # the emulator's received bytes at the previous request
        self.tx_base = tx_base        # the emulator's sent bytes when the client connected


class ControlServer:
    """The listening socket (``path``; a fresh temporary one by default) and its connections.

    An existing file at ``path`` that is not a socket is refused (``FileExistsError``), never
    removed; a stale socket left by a previous emulator is replaced.

    Parameters
    ----------
    path : str or os.PathLike, optional
        Where the socket is bound; a fresh temporary directory's ``control.sock`` by default.
    barrier_timeout_s : float, optional
        Longest the bus thread waits for the pty bytes a request announced before answering
        ``error``, s (finite, > 0; :data:`BARRIER_TIMEOUT_S` by default). The bus serves the pty
        meanwhile but no other control request, so a client announcing bytes nobody writes holds
        robot time this long.
    """

    def __init__(self, path: str | os.PathLike | None = None, barrier_timeout_s: float = BARRIER_TIMEOUT_S):
        if not (math.isfinite(barrier_timeout_s) and barrier_timeout_s > 0):
            raise ValueError(f"barrier timeout must be a finite number of seconds > 0, got {barrier_timeout_s!r}")
        self.barrier_timeout_s = float(barrier_timeout_s)
        self._tmpdir = None
        if path is None:
            self._tmpdir = tempfile.mkdtemp(prefix="swerve-lockstep-")
            path = Path(self._tmpdir) / "control.sock"
        self.path = str(path)
        try:
            mode = os.lstat(self.path).st_mode
        except FileNotFoundError:
            mode = None
        if mode is not None:
            if not stat.S_ISSOCK(mode):
                raise FileExistsError(errno.EEXIST, f"{self.path} exists and is not a socket (remove it or "
                                                    f"choose another path)")
            os.unlink(self.path)
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._listener.bind(self.path)
        self._listener.listen(4)
        self._listener.setblocking(False)
        self._conns: dict[int, _Connection] = {}
        self._fds = (self._listener.fileno(),)

    def fds(self) -> tuple[int, ...]:
        """Descriptors the bus thread selects on: a new tuple whenever a connection comes or goes
        (the same object while none does)."""
        return self._fds

    def handle(self, fd: int, bus: ControlledBus) -> None:
        """Serve a readable descriptor (a new connection or request lines).

        Nothing a client sends stops the bus thread: a malformed request is answered with an
        ``error`` line, and a client that overruns :data:`MAX_LINE_BYTES` or stops reading its
        replies (its socket buffer full) is disconnected.
        """
        if fd == self._listener.fileno():
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, ConnectionAbortedError):
                return
            sock.setblocking(False)
            if len(self._conns) >= MAX_CLIENTS:
                try:
                    sock.send(f"error more than {MAX_CLIENTS} control clients; disconnected\n".encode("ascii"))
                except OSError:
                    pass
                sock.close()
                return
            self._conns[sock.fileno()] = _Connection(sock, bus.rx_bytes, bus.tx_bytes)
            self._fds = (self._listener.fileno(), *self._conns)
            return
        conn = self._conns.get(fd)
        if conn is None:
            return
        try:
            data = conn.sock.recv(RECV_CHUNK)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._drop(fd)
            return
        buf = conn.buffer
        start = len(buf)
        buf += data
        begin = 0
        while True:
            end = buf.find(b"\n", start)
            if end < 0:
                break
            reply = self._reply(conn, bytes(buf[begin:end]), bus)
            if not self._send(fd, conn, reply):
                return
            begin = start = end + 1
        del buf[:begin]
        if len(buf) > MAX_LINE_BYTES:
            self._send(fd, conn, f"error request line longer than {MAX_LINE_BYTES} bytes; disconnected")
            self._drop(fd)

    def _reply(self, conn: _Connection, line: bytes, bus: ControlledBus) -> str:
        if len(line) > MAX_LINE_BYTES:
            return f"error request line longer than {MAX_LINE_BYTES} bytes"
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError as exc:
            return f"error request is not ASCII text (byte 0x{line[exc.start]:02x} at {exc.start})"
        try:
            return self._answer(conn, text.split(), bus)
        except (ArithmeticError, LookupError, TypeError, ValueError, SwerveError) as exc:
            return f"error {type(exc).__name__}: {exc}"

    def _send(self, fd: int, conn: _Connection, reply: str) -> bool:
        """Queue one reply line without blocking; drops the client (False) if it cannot take it."""
        data = reply.encode("ascii", "backslashreplace") + b"\n"
        try:
            sent = conn.sock.send(data)
        except OSError:
            sent = -1
        if sent != len(data):           # its socket buffer is full: it stopped reading replies
            log.warning("control client dropped: it does not read its replies")
            self._drop(fd)
            return False
        return True

    def _answer(self, conn: _Connection, words: list[str], bus: ControlledBus) -> str:
        cmd, args = (words[0], words[1:]) if words else ("", [])
        try:
            if cmd == "info" and not args:
                return f"info {bus.control_info()} body {int(bus.world is not None)}"
            if cmd == "stats" and not args:
                return "stats " + " ".join(f"{k} {v}" for k, v in bus.counters().items())
            if cmd == "fault" and len(args) >= 3:
                tx, fault = int(args[0]), args[1:]
            elif cmd in ("advance", "now", "pose", "sent") and len(args) == (2 if cmd == "advance" else 1):
                tx = int(args[-1])
            else:
                return f"error unknown request {' '.join(words)!r}"
            if not 0 <= tx <= MAX_TX_BYTES:
                return f"error tx_bytes must be in [0, {MAX_TX_BYTES}], got {tx}"
            target = conn.rx_base + tx
            if not bus.receive_until(target, self.barrier_timeout_s):
                conn.rx_base = bus.rx_bytes
                return (f"error only {bus.rx_bytes - (target - tx)} of the {tx} announced bytes arrived "
                        f"within {self.barrier_timeout_s:g} s")
            conn.rx_base = target
            if cmd == "advance":
                asked, t_s = bus.robot_time_s(), float(args[0])
                if not math.isfinite(t_s) or t_s - asked > MAX_ADVANCE_S:
                    return (f"error advance to {t_s!r} s refused: at most {MAX_ADVANCE_S:g} s past "
                            f"robot time {asked!r} s per request")
                return f"at {bus.move_to(t_s)!r} {asked!r}"
            if cmd == "now":
                return f"at {bus.robot_time_s()!r}"
            if cmd == "sent":
                return f"sent {bus.robot_time_s()!r} {bus.tx_bytes - conn.tx_base}"
            bus.settle()
            if cmd == "fault":
                bus.inject_fault(fault[0], fault[1:])
                return "ok"
            t, (x, y, theta) = bus.true_state()
            return f"pose {bus.robot_time_s()!r} {float(x)!r} {float(y)!r} {float(theta)!r} {t!r}"
        except (ValueError, KeyError) as exc:
            return f"error {exc}"

    def _drop(self, fd: int) -> None:
        conn = self._conns.pop(fd, None)
        if conn is not None:
            conn.sock.close()
            self._fds = (self._listener.fileno(), *self._conns)

    def close(self) -> None:
        for fd in list(self._conns):
            self._drop(fd)
        self._listener.close()
        try:
            os.unlink(self.path)
        except OSError:
            pass
        if self._tmpdir is not None:
            try:
                os.rmdir(self._tmpdir)
            except OSError:
                pass
