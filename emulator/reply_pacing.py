"""When the emulated bus's replies go out, and which of them fault injection lets through.

:class:`ReplyPacer` sends the replies of one instruction. A clock that keeps robot time
(lockstep) charges their wire time, return delays and adapter hold in simulated time, and they
are written at once; otherwise each is written at its wall-clock due time (its Return Delay Time,
the broadcast slot, any injected delay and, with wire timing, its bytes at 10 bits per byte),
through the USB adapter's latency timer when one is modelled (:mod:`swerve.emulator.adapter`).
Drop and corrupt draws (:mod:`swerve.emulator.faults`) happen in reply order either way.
"""
from __future__ import annotations

import os
import threading
import time
from typing import Callable, Iterator, Sequence

from swerve.emulator.adapter import UsbAdapter, byte_arrivals
from swerve.emulator.bus_stats import Stats
from swerve.emulator.clock import PhysicsClock, StepWorld
from swerve.emulator.faults import Faults
from swerve.emulator.instructions import Reply
from swerve.emulator.pty_link import precise_timers

#: Replies of one exchange due within this window go out together, at the due time of the
#: latest of them (later than the cable for the earlier ones, never earlier); the reply that
#: ends the exchange goes out alone at its own due time unless it is already due.
GROUP_WRITE_S = 1e-3


class ReplyPacer:
    """Writes each instruction's replies when they are due (see the module docstring).

    Parameters
    ----------
    write : callable
        ``write(data)``: the bytes onto the pty.
    clock : PhysicsClock
        Offered every exchange's reply time (:meth:`PhysicsClock.on_replies`).
    world : StepWorld
        What the clock steps (the emulator), passed on to the clock.
    robot_time_s : callable
        Robot time now, s (where the adapter starts a lockstep exchange).
    faults : Faults
        Drop, corrupt and delay settings, drawn per reply.
    stats : Stats
        Counts ``replies_sent``, ``replies_dropped``, ``replies_corrupted``.
    adapter : UsbAdapter, optional
        The USB-serial adapter between the cable and the host.
    wire_timing : bool
        Pace wall-clock replies as on a cable (their bytes take ``byte_t`` each).
    stop : threading.Event
        Set when the bus closes: a long wait ends early.
    """

    def __init__(self, write: Callable[[bytes], None], clock: PhysicsClock, world: StepWorld,
                 robot_time_s: Callable[[], float], faults: Faults, stats: Stats,
                 adapter: UsbAdapter | None, wire_timing: bool, stop: threading.Event):
        self._write = write
        self.clock = clock
        self._world = world
        self._robot_time_s = robot_time_s
        self.faults = faults
        self.stats = stats
        self.adapter = adapter
        self.wire_timing = wire_timing
        self._stop = stop

    def send(self, replies: Sequence[Reply], start_t: float, byte_t: float) -> None:
        """Send ``replies`` as the bus would after an instruction that ended at ``start_t``
        (monotonic s), ``byte_t`` s per byte on the line.

        Each reply is due its delay (Return Delay Time, broadcast slot, injected delay) after the
        previous one, plus its bytes with wire timing; the due times are fixed from ``start_t``
        before anything is sent. No reply is written before it is due; replies due within
        :data:`GROUP_WRITE_S` of each other share one write, and the one that ends the exchange
        is written on its own at its due time (so the client sees the exchange end on time).
        """
        if not replies:
            return
        if self._charged(replies, byte_t):
            return
        wire_byte_t = byte_t if self.wire_timing else 0.0
        extra_s = self.faults.delay_s
        due, t = [], start_t
        frames, gaps = [], []
        for r, frame in self._surviving(replies):
            t += r.delay_s + extra_s + len(frame) * wire_byte_t   # the last byte leaves the cable then
            due.append(t)
            frames.append(frame)
            gaps.append(r.delay_s + extra_s)
        n = len(frames)
        if not n:
            return
        if self.adapter is not None and self.wire_timing:
            due = self._through_adapter(start_t, gaps, frames, byte_t)
        i = 0
        while i < n:
            now = time.monotonic()
            j = i
            while j + 1 < n and (due[j + 1] <= now
                                 or (j + 1 < n - 1 and due[j + 1] - due[i] <= GROUP_WRITE_S)):
                j += 1
            if due[j] > now:
                self._sleep_until(due[j])
            self._write(b"".join(frames[i:j + 1]))
            i = j + 1
        # the pty hands written bytes to the reader through a kernel worker; on a busy core it
        # waits until this thread blocks, so give it the core now (one syscall, no spinning)
        os.sched_yield()

    def _surviving(self, replies: Sequence[Reply]) -> Iterator[tuple[Reply, bytes]]:
        """``(reply, frame)`` for each reply fault injection lets through (``frame`` perhaps
        corrupted), drawing faults in reply order (a fast-read frame draws once); counts them."""
        faults = self.faults
        if faults.drop_rate <= 0 and faults.corrupt_rate <= 0:     # nothing to draw
            self.stats.replies_sent += len(replies)
            for r in replies:
                yield r, r.frame
            return
        fast_dropped = fast_drawn = False
        for r in replies:
            if r.fast:
                if not fast_drawn:
                    fast_dropped, fast_drawn = faults.should_drop(), True
                    if fast_dropped:
                        self.stats.replies_dropped += 1
                if fast_dropped:
                    continue
            elif faults.should_drop():
                self.stats.replies_dropped += 1
                continue
            frame, corrupted = faults.maybe_corrupt(r.frame)
            if corrupted:
                self.stats.replies_corrupted += 1
            self.stats.replies_sent += 1
            yield r, frame

    def _charged(self, replies: Sequence[Reply], byte_t: float) -> bool:
        """Offer the replies' wire time to the clock; if it charges it (lockstep), send them at
        once and return True. Fault draws happen in the same order as with wall pacing.

        With an adapter, the clock is also charged the time the adapter holds the last byte
        after it left the cable (``hold_s``); every reply's bytes count, a dropped one's too
        (its wire time is charged as well)."""
        extra_s, wire_s, answering, fast = self.faults.delay_s, 0, 0, 0
        latency = self.clock.reply_latency_s
        gaps = []
        for r in replies:
            size, delay_s = len(r.frame), r.delay_s + extra_s
            wire_s += delay_s + size * byte_t
            if r.fast:
                starts = not fast                   # a combined fast-read frame answers once
                fast = 1
            else:
                starts = True
                answering += 1
            gaps.append((delay_s + latency if starts else delay_s + 0.0, size))
        answering += fast
        hold_s, delivery = 0.0, None
        if self.adapter is not None:
            start = self._robot_time_s()
            delivery = self.adapter.plan(byte_arrivals(start, gaps, byte_t))
            hold_s = max(0.0, delivery.end_s - (start + wire_s + answering * latency))
        if not self.clock.on_replies(self._world, wire_s, answering, hold_s):
            return False
        if delivery is not None:
            self.adapter.commit(delivery)
        self._write(b"".join(frame for _, frame in self._surviving(replies)))
        return True

    def _through_adapter(self, start_t: float, gaps: list[float], frames: list[bytes],
                         byte_t: float) -> list[float]:
        """Wall time at which the host has each of ``frames`` (its last byte) through the
        adapter, the frames leaving the cable back to back from ``start_t`` after their ``gaps``."""
        delivery = self.adapter.plan(byte_arrivals(start_t, list(zip(gaps, map(len, frames))), byte_t))
        self.adapter.commit(delivery)
        ends, k = [], 0
        for f in frames:
            k += len(f)
            ends.append(delivery.times_s[k - 1])
        return ends

    def _sleep_until(self, deadline: float) -> None:
        """Block until ``deadline`` (monotonic s), never before it; long waits end early when the
        bus closes. The calling thread gets fine timer slack first (:func:`precise_timers`)."""
        precise_timers()
        remaining = deadline - time.monotonic()
        if remaining > 2e-3:
            self._stop.wait(remaining)
        while (remaining := deadline - time.monotonic()) > 0 and not self._stop.is_set():
            time.sleep(remaining)
