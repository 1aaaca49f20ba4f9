"""The USB-serial adapter between the host and the cable (a U2D2: an FTDI FT232H-class chip).

Bytes a servo puts on the cable do not reach the host when their stop bit ends: the adapter
buffers them and sends them over USB in bulk packets. Sources (facts only, paraphrased):

* FTDI application note AN232B-04, "Data Throughput, Latency and Handshaking", §3 (data from
  the device to the host): a full-speed bulk packet carries 64 bytes, 2 of them modem-status
  bytes, so at most 62 data bytes; the chip sends when that packet is full, or when its
  **latency timer** expires. The timer counts the time since the chip last sent to the host
  and restarts on every send; on expiry it sends the status bytes and whatever data it holds
  (so an idle adapter sends a status-only packet every period). Default 16 ms.
* Linux commit db9240662a44 ("USB: serial: ftdi_sio: only allow valid latency timer values",
  2017): valid values are 1..255 ms in 1 ms steps; the chip takes the invalid 0 as 1 ms, which
  is why 0 is refused here rather than modelled.
* ROBOTIS e-Manual, DYNAMIXEL Wizard 2.0 / U2D2, "USB Latency Setting": the adapter ships at
  16 ms; ROBOTIS recommends 1 ms
  (https://emanual.robotis.com/docs/en/software/dynamixel/dynamixel_wizard2/#usb-latency-setting).
* DynamixelSDK issues #330 and #288 (https://github.com/ROBOTIS-GIT/DynamixelSDK/issues/330,
  /288): one read taking about 15 ms at the 16 ms default, a few ms after setting 1 ms.
* USB 2.0 specification §5.8 / §8.4.3: a full-speed bus runs in 1 ms frames (one Start-of-Frame
  each). Modelling choice (UNCONFIRMED in its detail): a packet the adapter has ready reaches
  the host at the next frame boundary of the host's clock; several packets may arrive in one
  frame. The host-to-adapter direction is not delayed here.

:func:`deliver` is the pure model: from the times each byte reached the adapter (its stop bit
ended on the cable) to the times the host has them. :class:`UsbAdapter` keeps the one piece of
state between exchanges (when the chip last sent) and is what the emulator is composed with
(:class:`swerve.emulator.server.Emulator` ``adapter=``); it applies in lockstep robot time and,
with ``--wire-timing``, on the wall clock.
"""
from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

from swerve.core.errors import ConfigError
from swerve.driver.adapter_latency import ADAPTER_LATENCY_MAX_MS as LATENCY_MAX_MS
from swerve.driver.adapter_latency import ADAPTER_LATENCY_MIN_MS as LATENCY_MIN_MS

#: FTDI full-speed bulk packet: 64 bytes, of which 2 are modem status (AN232B-04 §3).
PACKET_BYTES = 64
STATUS_BYTES = 2
#: The chip's factory latency timer (AN232B-04; the U2D2 as shipped), ms.
FACTORY_LATENCY_MS = 16
#: Full-speed USB frame, s (USB 2.0 §5.8).
USB_FRAME_S = 1e-3
#: Slack when a time is compared with the frame grid, in frames (float round-off).
_GRID_SLACK = 1e-6


def check_latency_ms(value: float, what: str = "adapter latency") -> int:
    """``value`` as a whole number of ms in 1..255, or :class:`ConfigError` naming the problem."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{what}: expected a whole number of ms in {LATENCY_MIN_MS}..{LATENCY_MAX_MS}, "
                          f"got {value!r}")
    if not math.isfinite(value) or value != int(value) or not LATENCY_MIN_MS <= value <= LATENCY_MAX_MS:
        hint = " (0 is not a valid FTDI latency timer; the chip would run it as 1 ms)" if value == 0 else ""
        raise ConfigError(f"{what}: {value!r} ms is not a latency timer value: the FTDI timer takes a "
                          f"whole number of ms in {LATENCY_MIN_MS}..{LATENCY_MAX_MS}{hint}")
    return int(value)


@dataclass(frozen=True)
class AdapterSettings:
    """An FTDI USB-serial adapter's settings.

    Parameters
    ----------
    latency_ms : int
        Latency timer, ms (1..255; 16 as shipped, 1 after the recommended fix).
    frame_s : float
        USB frame, s: packets reach the host on this grid (full speed: 1 ms).
    payload_bytes : int
        Data bytes per USB packet (64 - 2 status bytes).
    """

    latency_ms: int = 1
    frame_s: float = USB_FRAME_S
    payload_bytes: int = PACKET_BYTES - STATUS_BYTES

    def __post_init__(self):
        check_latency_ms(self.latency_ms)
        if not (math.isfinite(self.frame_s) and self.frame_s > 0):
            raise ConfigError(f"USB frame must be a finite time > 0 s, got {self.frame_s!r}")
        if isinstance(self.payload_bytes, bool) or not isinstance(self.payload_bytes, int) \
                or self.payload_bytes < 1:
            raise ConfigError(f"USB packet payload must be a whole number of bytes >= 1, got {self.payload_bytes!r}")

    @property
    def latency_s(self) -> float:
        return self.latency_ms * 1e-3


@dataclass(frozen=True)
class Delivery:
    """What :func:`deliver` computed: the USB packets that carried bytes, as ``packets[k] =
    (end, t_s)`` (bytes up to index ``end``, exclusive, reach the host at ``t_s``); and
    ``last_send_s``, when the adapter last sent a packet (the latency timer restarts there)."""

    packets: tuple[tuple[int, float], ...]
    last_send_s: float

    @cached_property
    def times_s(self) -> tuple[float, ...]:
        """When the host has each byte, s, shape (n,)."""
        out: list[float] = []
        for end, t in self.packets:
            out.extend([t] * (end - len(out)))
        return tuple(out)

    @property
    def end_s(self) -> float:
        """When the host has the last byte (``last_send_s`` if there were no bytes)."""
        return self.packets[-1][1] if self.packets else self.last_send_s


def _next_frame(settings: AdapterSettings, t: float) -> float:
    """The first frame boundary at or after ``t``."""
    f = settings.frame_s
    return math.ceil(t / f - _GRID_SLACK) * f


class ByteArrivals(Sequence):
    """Arrival time of every byte of back-to-back frames on the cable, computed per index.

    ``frames``: ``(gap_s, n_bytes)`` per frame, the gap (>= 0) before its first byte starts
    (Return Delay Time, reply latency); ``byte_s``: one byte's time on the wire (10 bits / baud,
    >= 0). The first frame's gap counts from ``start_s``. Item ``i`` is the time the stop bit of
    byte ``i`` ends, s; the times never decrease. Reading one costs a search over the frames, so
    :func:`deliver` touches a few bytes per USB packet instead of every byte, and finds where a
    packet ends with :meth:`bisect_right`, arithmetic within a frame.
    """

    def __init__(self, start_s: float, frames: Sequence[tuple[float, int]], byte_s: float):
        if not byte_s >= 0:
            raise ValueError(f"byte time must be >= 0 s, got {byte_s!r}")
        self._byte_s = byte_s
        self._bases: list[float] = []      # per frame with bytes: the time its first byte starts
        self._firsts: list[int] = []       # per frame with bytes: the index of its first byte
        t, n_all = start_s, 0
        for gap_s, n in frames:
            if not gap_s >= 0:
                raise ValueError(f"gap before a frame must be >= 0 s, got {gap_s!r}")
            t += gap_s
            if n > 0:
                self._bases.append(t)
                self._firsts.append(n_all)
            n_all += n
            t += n * byte_s
        self._n = n_all

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(self._n))]
        if not 0 <= i < self._n:
            if i < 0 and i + self._n >= 0:
                i += self._n
            else:
                raise IndexError("byte index out of range")
        return self.time_of(i)

    def time_of(self, i: int) -> float:
        """Item ``i`` for an index ``0 <= i < len(self)`` (unchecked), s."""
        firsts = self._firsts
        f = bisect_right(firsts, i) - 1
        return self._bases[f] + (i - firsts[f] + 1) * self._byte_s

    def bisect_right(self, t: float, lo: int, hi: int) -> int:
        """``bisect.bisect_right(self, t, lo, hi)``: the first index in ``lo..hi-1`` whose time
        is after ``t`` s (``hi`` if none), each time computed as indexing computes it."""
        if lo >= hi:
            return lo
        firsts, bases, byte_s = self._firsts, self._bases, self._byte_s
        f = bisect_right(firsts, lo) - 1
        i = lo
        while i < hi:
            first, base = firsts[f], bases[f]
            f += 1
            end = min(firsts[f] if f < len(firsts) else self._n, hi)
            if base + (end - first) * byte_s <= t:      # the frame's last byte in range is in by t
                i = end
                continue
            while i < end - 1:                          # its first byte after t, in i..end-1
                mid = (i + end - 1) // 2
                if base + (mid - first + 1) * byte_s > t:
                    end = mid + 1
                else:
                    i = mid + 1
            return i
        return hi


def deliver(settings: AdapterSettings, arrivals_s: Sequence[float], last_send_s: float = 0.0) -> Delivery:
    """When the host has each byte that reached the adapter at ``arrivals_s`` (s, non-decreasing).

    The adapter last sent at ``last_send_s``; its latency timer then expires every ``latency``
    after its latest send (an expiry with nothing buffered still sends the status bytes and
    restarts the timer). Bytes collect in a packet until it holds ``payload_bytes`` (it goes at
    once) or the timer expires (it goes with what it holds); the host has a packet at the first
    USB frame boundary at or after it went. A byte that arrived before ``last_send_s`` (the
    previous exchange's packet already left) waits for the next send.

    Parameters
    ----------
    settings : AdapterSettings
    arrivals_s : sequence of float, shape (n,)
        Time each byte's stop bit ended on the cable, s (any time origin; the frame grid is at
        whole multiples of ``frame_s`` of that origin). A :class:`ByteArrivals` is taken as
        ordered without a check, and only the bytes at packet edges are read.
    last_send_s : float
        When the adapter last sent, s.

    Returns
    -------
    Delivery
        The packets with the host time of each, and the new ``last_send_s``.
    """
    latency = settings.latency_s
    cap = settings.payload_bytes
    n = len(arrivals_s)
    if isinstance(arrivals_s, ByteArrivals):
        find, at = arrivals_s.bisect_right, arrivals_s.time_of
    else:
        if any(b < a for a, b in zip(arrivals_s, arrivals_s[1:])):
            raise ValueError("byte arrival times must be non-decreasing")
        at = arrivals_s.__getitem__

        def find(t: float, lo: int, hi: int) -> int:
            return bisect_right(arrivals_s, t, lo, hi)
    packets: list[tuple[int, float]] = []
    t_ref = last_send_s
    i = 0
    while i < n:
        first = max(at(i), t_ref)
        periods = max(1, math.ceil((first - t_ref) / latency - _GRID_SLACK))
        expiry = t_ref + periods * latency
        # the bytes in by the expiry, at most a full packet (the times are in order): all of
        # them when the last one is (a full packet, or the rest of the bytes), else a search
        hi = min(n, i + cap)
        limit = expiry + _GRID_SLACK * settings.frame_s
        j = hi if at(hi - 1) <= limit else find(limit, i, hi - 1)
        sent = max(at(j - 1), t_ref) if j - i == cap else expiry
        t_ref = _next_frame(settings, sent)
        if j > i:
            packets.append((j, t_ref))
        i = j
    return Delivery(tuple(packets), t_ref)


def byte_arrivals(start_s: float, frames: Sequence[tuple[float, int]], byte_s: float) -> ByteArrivals:
    """Arrival time of every byte of back-to-back frames on the cable (a :class:`ByteArrivals`).

    ``frames``: ``(gap_s, n_bytes)`` per frame, the gap before its first byte starts (Return
    Delay Time, reply latency); ``byte_s``: one byte's time on the wire (10 bits / baud).
    The first frame's gap counts from ``start_s``. Item ``i`` is the time byte ``i``'s stop bit ends.
    """
    return ByteArrivals(start_s, frames, byte_s)


class UsbAdapter:
    """An adapter in use: its settings and when it last sent (the phase of its latency timer).

    :meth:`plan` computes a :class:`Delivery` without changing the adapter; :meth:`commit` takes
    it (the emulator commits only what it charges or paces). Robot time (lockstep) and the
    monotonic clock (wall) each start the adapter at 0 s of their own clock.
    """

    def __init__(self, settings: AdapterSettings = AdapterSettings()):
        self.settings = settings
        self.last_send_s = 0.0

    @property
    def latency_ms(self) -> int:
        return self.settings.latency_ms

    def plan(self, arrivals_s: Sequence[float]) -> Delivery:
        return deliver(self.settings, arrivals_s, self.last_send_s)

    def commit(self, delivery: Delivery) -> None:
        self.last_send_s = max(self.last_send_s, delivery.last_send_s)

    def __repr__(self) -> str:
        return f"UsbAdapter(latency_ms={self.latency_ms}, frame_s={self.settings.frame_s!r})"


__all__ = ["AdapterSettings", "ByteArrivals", "Delivery", "UsbAdapter", "byte_arrivals", "check_latency_ms", "deliver",
           "FACTORY_LATENCY_MS", "LATENCY_MAX_MS", "LATENCY_MIN_MS"]
