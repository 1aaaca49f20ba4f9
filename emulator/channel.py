"""The emulator process's connection between parent and child: messages and the shared block.

:class:`Channel` carries the start request, the fault calls and the final counters as pickled
Python values over a stream socket, each preceded by its length (4 bytes, big-endian), in
both directions. The true pose travels apart, through the shared block :data:`SHARED_STATE`.
Both ends are this module's only (:mod:`swerve.emulator.spawn`, :mod:`swerve.emulator.child`):
the child imports it and nothing of :mod:`multiprocessing` (~10–15 ms of its start-up).
"""
from __future__ import annotations

import pickle
import select
import socket
import struct

#: The shared true-state block: ``[sim_time_s, x_m, y_m, theta_rad]`` as native doubles.
SHARED_STATE = struct.Struct("4d")
#: The length of a message in front of it, bytes.
_HEAD = struct.Struct("!I")


class Channel:
    """One end of the connection: :meth:`send` a value, :meth:`recv` the next one (``EOFError``
    once the other end has closed), :meth:`poll` for one with a timeout, :meth:`close`."""

    def __init__(self, sock: socket.socket):
        self._sock = sock

    @classmethod
    def from_fd(cls, fd: int) -> "Channel":
        """The end whose socket is the inherited file descriptor ``fd``."""
        return cls(socket.socket(fileno=fd))

    def send(self, value) -> None:
        """Send ``value`` (picklable); ``OSError`` (e.g. ``BrokenPipeError``) if the other end is gone."""
        data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
        self._sock.sendall(_HEAD.pack(len(data)) + data)

    def recv(self):
        """The next value sent by the other end (blocks); ``EOFError`` if it closed first."""
        (size,) = _HEAD.unpack(self._read(_HEAD.size))
        return pickle.loads(self._read(size))

    def poll(self, timeout_s: float) -> bool:
        """Whether a value (or the other end's close) can be read within ``timeout_s`` seconds."""
        readable, _, _ = select.select([self._sock], [], [], timeout_s)
        return bool(readable)

    def close(self) -> None:
        """Close this end (the other end's :meth:`recv` then raises ``EOFError``)."""
        self._sock.close()

    def _read(self, size: int) -> bytes:
        buf = bytearray()
        while len(buf) < size:
            chunk = self._sock.recv(size - len(buf))
            if not chunk:
                raise EOFError("the other end of the emulator's channel closed")
            buf += chunk
        return bytes(buf)
